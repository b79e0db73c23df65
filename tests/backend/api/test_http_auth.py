"""REST authentication and roles against a real server (auth on, as every test server runs)."""

from __future__ import annotations

import asyncio
import re
import subprocess
import time

import httpx
import pytest
import websockets
from websockets.exceptions import ConnectionClosed

from tests.backend.helpers import ProbeRobot, wait_robot
from tests.support.procs import TEST_ADMIN_TOKEN, VENV_BIN, ServerProcess, base_env, wait_for

PUBLIC = {("GET", "/api/health"), ("POST", "/api/auth/login"), ("POST", "/api/auth/logout"), ("POST", "/api/enrol")}
PARAMS = {
    "robot_id": "r1",
    "command_id": "c1",
    "token_id": "tok_x",
    "username": "someone",
    "alarm_id": "1",
    "run_id": "1",
    "mission_id": "m1",
}


def _operations(spec: dict) -> list[tuple[str, str]]:
    ops = []
    for path, item in spec["paths"].items():
        for method in item:
            if method in ("get", "post", "put", "patch", "delete"):
                ops.append((method.upper(), path))
    return ops


def _fill(path: str) -> str:
    return re.sub(r"\{(\w+)\}", lambda m: PARAMS[m.group(1)], path)


def test_every_api_route_needs_a_valid_token(server):
    with server.client() as admin:
        spec = admin.get("/openapi.json").json()
    ops = _operations(spec)
    assert len(ops) >= 25 and ("POST", "/api/robots/{robot_id}/commands") in ops
    checked = 0
    for credentials in (
        {},
        {"Authorization": "Bearer flt_not-a-real-token"},
        {"Authorization": "Basic eDp5"},
        {"Cookie": "fleet_session=fls_forged"},
    ):
        with httpx.Client(base_url=server.base_url, timeout=15, headers=credentials) as c:
            for method, path in ops:
                if (method, path) in PUBLIC:
                    continue
                r = c.request(method, _fill(path), json={} if method in ("POST", "PATCH") else None)
                assert r.status_code == 401, (credentials, method, path, r.status_code, r.text)
                assert r.headers["www-authenticate"] == "Bearer"
                assert "robots" not in r.text and "r1" not in r.text  # nothing but the refusal
                checked += 1
    assert checked == 4 * (len(ops) - len(PUBLIC))
    # the UI shell and the spec are public (no data in them)
    with server.client(anonymous=True) as c:
        assert c.get("/docs").status_code == 200
        assert c.get("/openapi.json").status_code == 200


def test_public_health_is_minimal(server):
    with server.client(anonymous=True) as c:
        h = c.get("/api/health").json()
    assert h["status"] == "ok" and h["auth"] == "on" and h["version"]
    assert h["mqtt"] == {"url": None, "connected": True} and h["database"] == {"url": None, "ok": True}
    assert h["rejects"] is None
    with server.client() as c:
        full = c.get("/api/health").json()
    assert full["mqtt"]["url"] == server.broker.url and full["rejects"] is not None


def test_roles(server, mqtt_probe, role_client):
    robot = ProbeRobot(mqtt_probe, "r1")
    robot.status()
    viewer, operator, admin = role_client("viewer"), role_client("operator"), role_client("admin")
    wait_robot(viewer, "r1", lambda r: r["online"])
    drive = {"command": "move_forward", "args": {"speed": 0.2}}

    # viewer: reads everything, may press the e-stop, may not drive, release or administer
    assert viewer.get("/api/robots").json()[0]["id"] == "r1"
    assert viewer.get("/api/events").status_code == 200
    assert viewer.get("/metrics").status_code == 200
    r = viewer.post("/api/robots/r1/commands", json=drive)
    assert r.status_code == 403 and "operator" in r.json()["detail"]
    assert viewer.post("/api/robots/r1/commands", json={"command": "stop"}).status_code == 403
    me = viewer.get("/api/auth/me").json()
    assert me == {
        "name": "test-viewer",
        "role": "viewer",
        "kind": "token",
        "username": None,
        "auth": True,
        "subject": me["subject"],
    } and me["subject"].startswith("token:")
    assert viewer.post("/api/estop", json={"reason": "viewer saw danger"}).status_code == 202
    assert viewer.post("/api/estop/release", json={}).status_code == 403
    assert viewer.get("/api/tokens").status_code == 403
    assert viewer.post("/api/tokens", json={"name": "x", "role": "admin"}).status_code == 403

    # operator: drives and releases, no administration
    assert operator.post("/api/estop/release", json={}).status_code == 202
    r = operator.post("/api/robots/r1/commands", json=drive)
    assert r.status_code == 202, r.text
    assert robot.next_command()["id"] == r.json()["id"]
    assert operator.get("/api/users").status_code == 403
    assert operator.delete("/api/tokens/tok_x").status_code == 403

    # admin: everything
    assert admin.get("/api/tokens").status_code == 200
    assert admin.post("/api/robots/r1/commands", json={"command": "stop"}).status_code == 202
    # nothing a viewer tried reached the robot: the only commands are the operator's and the admin's
    robot.probe.wait(lambda m: m.topic == "fleet/r1/cmd" and b'"stop"' in m.payload)
    assert [c["command"] for c in robot.commands_received()] == ["move_forward", "stop"]


async def _ws_refusal(url: str, token: str) -> tuple[int, str]:
    """How the server closes a WebSocket opened with ``token`` (it must, before any data)."""
    async with websockets.connect(url, additional_headers={"Authorization": f"Bearer {token}"}) as ws:
        try:
            await asyncio.wait_for(ws.recv(), 10)
        except ConnectionClosed as exc:
            assert exc.rcvd is not None
            return exc.rcvd.code, exc.rcvd.reason
    raise AssertionError(f"{url}: data on a socket that should have been refused")


def test_a_metrics_token_scrapes_and_does_nothing_else(server):
    """Issue 29 #8: Prometheus's credential may read GET /metrics and nothing else: no API route (neither a
    read nor the e-stop), no socket, not even health's details."""
    with server.client() as admin:
        r = admin.post("/api/tokens", json={"name": "prometheus", "role": "metrics"})
        assert r.status_code == 201 and r.json()["role"] == "metrics", r.text
        spec = admin.get("/openapi.json").json()
    with server.client(r.json()["token"]) as scrape:
        metrics = scrape.get("/metrics")
        assert metrics.status_code == 200 and "fleet_robots_online" in metrics.text
        from backend.core.security import Role
        from tests.backend.api.test_route_roles import EXPECTED as ROLES

        refused = 0
        for method, path in _operations(spec):
            if ROLES.get((method, path)) in ("public", Role.METRICS):  # a route the table lets anyone call
                continue
            got = scrape.request(method, _fill(path), json={} if method in ("POST", "PATCH", "PUT") else None)
            assert got.status_code == 403, (method, path, got.status_code, got.text)
            refused += 1
        assert refused >= 25
        estop = scrape.post("/api/estop", json={"reason": "a scraper cannot stop the fleet"})
        assert estop.status_code == 403 and "viewer role required (you are metrics)" in estop.json()["detail"]
        health = scrape.get("/api/health").json()
        assert health["rejects"] is None and health["mqtt"]["url"] is None  # what anyone may see, no more
    for path in ("/ws", "/ws/camera/r1", "/ws/control/r1"):
        code, reason = asyncio.run(_ws_refusal(f"ws://127.0.0.1:{server.port}{path}", r.json()["token"]))
        assert code == 1008 and "role required" in reason, (path, code, reason)


def test_tokens_are_shown_once_stored_hashed_and_revocable(server, database_url):
    with server.client() as admin:
        r = admin.post("/api/tokens", json={"name": "ci-script", "role": "operator"})
        assert r.status_code == 201
        created = r.json()
        secret = created["token"]
        assert secret.startswith("flt_") and len(secret) > 40
        listed = admin.get("/api/tokens").json()
        assert [t["name"] for t in listed] == ["ci-script"]
        assert "token" not in listed[0] and secret not in admin.get("/api/tokens").text
        with server.client(secret) as script:
            assert script.get("/api/auth/me").json()["role"] == "operator"
            assert admin.get("/api/tokens").json()[0]["last_used_at"] is not None
            assert admin.delete(f"/api/tokens/{created['id']}").status_code == 204
            assert script.get("/api/robots").status_code == 401  # at once
        assert admin.get("/api/tokens").json()[0]["revoked"] is True
        assert admin.delete("/api/tokens/tok_nonexistent").status_code == 404
        r = admin.post("/api/tokens", json={"name": "x", "role": "superuser"})
        assert r.status_code == 422
        # `true` is not a lifetime (lax parsing read it as 1 s and created the token)
        r = admin.post("/api/tokens", json={"name": "x", "role": "operator", "expires_in_s": True})
        assert r.status_code == 422 and "expires_in_s" in r.text
        assert [t["name"] for t in admin.get("/api/tokens").json()] == ["ci-script"]
        # an expired token is refused
        short = admin.post("/api/tokens", json={"name": "short", "role": "viewer", "expires_in_s": 0.5}).json()
    wait_for(lambda: time.time() > short["expires_at"], 5, what="the token's expiry")
    with server.client(short["token"]) as c:
        assert c.get("/api/robots").status_code == 401
    # the database holds only hashes
    from sqlalchemy import create_engine, text

    engine = create_engine(database_url)
    try:
        with engine.connect() as conn:
            dump = repr(conn.execute(text("SELECT * FROM api_tokens")).fetchall())
    finally:
        engine.dispose()
    assert secret not in dump and short["token"] not in dump


def _login(server: ServerProcess, username: str, password: str, **headers: str) -> httpx.Response:
    with server.client(anonymous=True) as c:
        return c.post("/api/auth/login", json={"username": username, "password": password}, headers=headers)


def test_login_cookie_flow(server):
    with server.client() as admin:
        r = admin.post("/api/users", json={"username": "ada", "password": "correct horse", "role": "operator"})
        assert r.status_code == 201 and r.json()["role"] == "operator" and "password" not in r.text
        assert admin.post("/api/users", json={"username": "ada", "password": "x" * 10}).status_code == 409
        assert admin.post("/api/users", json={"username": "bob", "password": "short"}).status_code == 422

    assert _login(server, "ada", "wrong password").status_code == 401
    assert _login(server, "nobody", "correct horse").status_code == 401
    r = _login(server, "ada", "correct horse")
    assert r.status_code == 200 and r.json()["role"] == "operator"
    cookie = r.headers["set-cookie"]
    assert cookie.startswith("fleet_session=fls_")
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Path=/" in cookie
    session = r.cookies["fleet_session"]

    with httpx.Client(base_url=server.base_url, timeout=15, cookies={"fleet_session": session}) as browser:
        me = browser.get("/api/auth/me").json()
        assert me["name"] == "ada" and me["kind"] == "session" and me["role"] == "operator"
        assert browser.get("/api/robots").status_code == 200
        # cookie-authenticated writes must come from this origin (CSRF)
        evil = browser.post("/api/estop", json={}, headers={"Origin": "http://evil.example"})
        assert evil.status_code == 403
        same = browser.post("/api/estop", json={}, headers={"Origin": server.base_url})
        assert same.status_code == 202
        assert browser.post("/api/estop/release", json={}, headers={"Origin": server.base_url}).status_code == 202
        # a role change applies to the running session at once
        with server.client() as admin:
            assert admin.patch("/api/users/ada", json={"role": "viewer"}).json()["role"] == "viewer"
        assert browser.post("/api/estop/release", json={}).status_code == 403
        # logout ends the session on the server, not only in the browser
        r = browser.post("/api/auth/logout")
        assert r.status_code == 204 and 'fleet_session=""' in r.headers["set-cookie"]
    with httpx.Client(base_url=server.base_url, timeout=15, cookies={"fleet_session": session}) as replay:
        assert replay.get("/api/robots").status_code == 401

    # a new password or disabling the user ends every session
    session2 = _login(server, "ada", "correct horse").cookies["fleet_session"]
    with server.client() as admin:
        assert admin.patch("/api/users/ada", json={"disabled": True}).status_code == 200
    with httpx.Client(base_url=server.base_url, timeout=15, cookies={"fleet_session": session2}) as c:
        assert c.get("/api/robots").status_code == 401
    assert _login(server, "ada", "correct horse").status_code == 401
    with server.client() as admin:
        assert admin.delete("/api/users/ada").status_code == 204
        assert admin.get("/api/users/ada").status_code == 404


def test_login_brute_force_is_slowed(broker, database_url, workdir):
    # a refill slower than any machine's 7 logins: at the default 0.5/s, 7 scrypt checks taking over 2 s on a
    # loaded machine earned a token back and the 6th guess got a 401 (the burst is what is under test)
    server = ServerProcess(broker, database_url, workdir, FLEET_LOGIN_RATE_PER_S="0.01")
    server.start()
    try:
        _brute_force_is_slowed(server)
    finally:
        server.stop()


def _brute_force_is_slowed(server: ServerProcess) -> None:
    codes = [_login(server, "admin", f"guess-{i}").status_code for i in range(7)]
    assert codes[:5] == [401] * 5 and codes[5:] == [429, 429]
    r = _login(server, "admin", "guess-x")
    assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1


def test_request_limits_and_headers(server):
    with server.client() as c:
        big = {"command": "stop", "source": "x" * 70_000}
        r = c.post("/api/robots/r1/commands", json=big)
        assert r.status_code == 413
        # chunked (no Content-Length): refused while streaming

        def chunks():
            for _ in range(100):
                yield b" " * 1024

        r = c.post("/api/robots/r1/commands", content=chunks(), headers={"content-type": "application/json"})
        assert r.status_code == 413
        assert c.get("/api/health").status_code == 200  # the server is fine
        # a repeated query parameter means different things to different readers: refused
        r = c.get("/api/events", params=[("robot_id", "a"), ("robot_id", "b")])
        assert r.status_code == 422 and "robot_id" in r.json()["detail"]
        r = c.get("/api/events", params={"robot_id": "a"})
        assert r.status_code == 200
        assert r.headers["x-content-type-options"] == "nosniff" and r.headers["x-frame-options"] == "DENY"


def _cli(server: ServerProcess, *args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(VENV_BIN / "fleet-server"), *args],
        env=base_env(FLEET_DATABASE_URL=server.database_url),
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_cli_create_admin_and_users_add(server):
    out = _cli(server, "create-admin", "--name", "bootstrap")
    assert out.returncode == 0, out.stderr
    token = out.stdout.strip()
    assert token.startswith("flt_") and "\n" not in token
    with server.client(token) as c:
        assert c.get("/api/auth/me").json()["role"] == "admin"
        assert [t["name"] for t in c.get("/api/tokens").json()] == ["bootstrap"]
    out = _cli(server, "users", "add", "grace", "--role", "operator", "--password-stdin", stdin="s3cret-enough\n")
    assert out.returncode == 0, out.stderr
    assert _login(server, "grace", "s3cret-enough").json()["role"] == "operator"
    out = _cli(server, "users", "add", "grace", "--role", "admin", "--password-stdin", stdin="new-password\n")
    assert out.returncode == 0  # the same command resets password and role
    assert _login(server, "grace", "new-password").json()["role"] == "admin"
    assert "grace\tadmin" in _cli(server, "users", "list").stdout
    bad = _cli(server, "users", "add", "eve", "--password-stdin", stdin="short\n")
    assert bad.returncode == 1 and "password" in bad.stderr


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"FLEET_SECRET_KEY": "s" * 40, "FLEET_ADMIN_TOKEN": "short-token"}, "FLEET_ADMIN_TOKEN is too short"),
        ({"FLEET_SECRET_KEY": "", "FLEET_ADMIN_TOKEN": TEST_ADMIN_TOKEN}, "FLEET_SECRET_KEY"),
        ({"FLEET_SECRET_KEY": "s" * 40, "FLEET_ADMIN_TOKEN": TEST_ADMIN_TOKEN, "FLEET_AUTH": "off"}, "FLEET_AUTH=off"),
    ],
)
def test_production_refuses_weak_settings(broker, database_url, workdir, env, message):
    s = ServerProcess(broker, database_url, workdir, FLEET_ENV="production", **env)
    s.start(wait=False)
    try:
        assert s.proc is not None and s.proc.wait(30) == 2
    finally:
        s.stop()
    out = s.output()
    assert message in out and "s" * 40 not in out and TEST_ADMIN_TOKEN not in out  # secrets never echoed


def test_auth_off_is_loud(broker, database_url, workdir):
    s = ServerProcess(broker, database_url, workdir, FLEET_AUTH="off")
    s.start()
    try:
        with s.client(anonymous=True) as c:
            assert c.get("/api/health").json()["auth"] == "off"
            assert c.get("/api/robots").status_code == 200
            assert c.get("/api/auth/me").json()["role"] == "admin"
        assert "WARNING" in s.output() and "AUTHENTICATION IS OFF" in s.output()
    finally:
        s.stop()
