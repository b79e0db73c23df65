"""``schemathesis run --checks all`` against a fresh server (empty database, no robot connected, so nothing
generated can drive one), authenticated as admin: every check passes. Among them: every status a route
answers is documented, what the schema allows is accepted and what it forbids is refused (query patterns
and lengths included), responses match their schemas, a 405 names the allowed methods, and routes that
need credentials refuse requests without them. Every error body carries a machine-readable ``code``."""

from __future__ import annotations

import http.client
import json
import os
import subprocess
import urllib.parse
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.support.procs import VENV_BIN, Broker, ServerProcess

HOOKS = "tests.backend.api.schemathesis_hooks"
REPO = Path(__file__).resolve().parents[3]
#: one operation's expected answers to positive data (why: in the file)
CONFIG = Path(__file__).with_name("schemathesis.toml")


@pytest.fixture(scope="module")
def fresh(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    workdir = Path(tmp_path_factory.mktemp("schemathesis-all"))
    broker = Broker(workdir)
    broker.start()
    server = ServerProcess(broker, f"sqlite:///{workdir / 'fleet.db'}", workdir)
    try:
        server.start()
        yield server
        assert server.alive(), server.output()[-3000:]
    finally:
        server.stop()
        broker.stop()


@pytest.mark.slow
@pytest.mark.timeout(600)  # 69 operations since issue 29 (enrolment, legacy robots): 4 min in CI's parallel lane
def test_schemathesis_with_every_check_reports_nothing(fresh: ServerProcess, tmp_path: Path) -> None:
    with fresh.client() as http:
        assert http.get("/api/robots").json() == []  # nothing to drive
    assert fresh.token
    done = subprocess.run(
        [
            str(VENV_BIN / "schemathesis"),
            "--config-file",
            str(CONFIG),
            "run",
            f"{fresh.base_url}/openapi.json",
            "--checks",
            "all",
            "--header",
            f"Authorization: Bearer {fresh.token}",
            "--max-examples",
            "20",
            "--no-color",
            *(["--seed", os.environ["FLEET_SCHEMATHESIS_SEED"]] if "FLEET_SCHEMATHESIS_SEED" in os.environ else []),
        ],
        cwd=tmp_path,  # schemathesis keeps its state in .schemathesis/ there
        env={**os.environ, "SCHEMATHESIS_HOOKS": HOOKS, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=900,
    )
    report = done.stdout + done.stderr
    failures = report.find("FAILURES")  # the failing cases with their curl lines, before the long warnings
    assert done.returncode == 0, report[failures : failures + 8000] if failures >= 0 else report[-12000:]
    assert "27/27" in report or "Selected:" in report


def test_the_joined_rules_the_hooks_put_right_are_refused_with_their_codes(fresh: ServerProcess) -> None:
    with fresh.client() as http:
        r = http.get("/api/events", params={"start": "2026-11-22T10:00:00Z", "end": "2026-11-22"})
        assert r.status_code == 422 and r.json()["code"] == "validation_error", r.text
        r = http.get("/api/telemetry", params={"raw": "true", "format": "json"})
        assert r.status_code == 422 and r.json()["code"] == "raw_json", r.text
        assert http.get("/api/telemetry", params={"raw": "true", "format": "csv"}).status_code == 200


@pytest.mark.parametrize(
    ("method", "path", "status", "code"),
    [
        ("GET", "/api/robots/ghost", 404, "unknown_robot"),
        ("GET", "/api/robots/ghost/streams", 404, "unknown_robot"),
        ("GET", "/api/robots/ghost/commands", 404, "unknown_robot"),
        ("GET", "/api/robots/ghost/telemetry", 404, "unknown_robot"),
        ("POST", "/api/robots/ghost/commands", 404, "unknown_robot"),
        ("GET", "/api/commands/nope", 404, "unknown_command"),
        ("GET", "/api/telemetry?robots=" + "r" * 70, 422, "validation_error"),
        ("GET", "/api/events?start=2026-02-30", 422, "validation_error"),
        ("GET", "/api/events?start=1700000000&start=1", 422, "repeated_query"),
        ("PUT", "/api/estop", 405, "method_not_allowed"),
    ],
)
def test_every_error_carries_its_code(fresh: ServerProcess, method: str, path: str, status: int, code: str) -> None:
    body = {"command": "stop"} if method == "POST" else None
    with fresh.client() as http:
        r = http.request(method, path, json=body)
    assert r.status_code == status and r.json()["code"] == code, r.text
    assert isinstance(r.json()["detail"], str | list)


def test_a_405_names_every_method_of_the_path(fresh: ServerProcess) -> None:
    with fresh.client() as http:
        r = http.put("/api/estop")
    assert r.status_code == 405 and r.headers["allow"] == "GET, POST"
    spec = httpx.get(f"{fresh.base_url}/openapi.json").json()
    assert sorted(m.upper() for m in spec["paths"]["/api/estop"]) == ["GET", "POST"]


def test_a_refused_login_and_a_missing_token_carry_codes(fresh: ServerProcess) -> None:
    with fresh.client(anonymous=True) as http:
        r = http.get("/api/robots")
        assert r.status_code == 401 and r.json()["code"] == "unauthorized"
        r = http.post("/api/auth/login", json={"username": "nobody", "password": "wrong-password"})
        assert r.status_code == 401 and r.json()["code"] == "bad_credentials"


def test_an_overlong_query_gets_the_routes_422_not_the_http_servers_bare_400(fresh: ServerProcess) -> None:
    """Found by schemathesis: 8,001 four-byte characters in ``robots`` make a 96 KB URL, which the
    default HTTP parser refused with a bare 400 before the route could say what was wrong."""
    query = urllib.parse.urlencode({"robots": "\U000310aa" * 8001, "streams": "position"})
    assert len(query) > 65536  # beyond httpx's and httptools' URL limits: sent by hand
    conn = http.client.HTTPConnection("127.0.0.1", fresh.port, timeout=15)
    try:
        conn.request("GET", f"/api/telemetry?{query}", headers={"Authorization": f"Bearer {fresh.token}"})
        r = conn.getresponse()
        body = r.read()
    finally:
        conn.close()
    assert r.status == 422 and json.loads(body)["code"] == "validation_error", body[:300]
