"""Schemathesis against the live server's OpenAPI spec, authenticated as admin, with a simulated robot
online: no 5xx for any generated request, and invalid data is rejected with a 4xx.

Kept small for CI (``max_examples`` per operation); ``?wait`` (long polling) is never generated.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.checks import negative_data_rejection, not_a_server_error

from tests.backend.helpers import wait_robot
from tests.support.procs import AgentProcess, Broker, ServerProcess

MAX_EXAMPLES = 20


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    workdir = Path(tmp_path_factory.mktemp("schemathesis"))
    broker = Broker(workdir)
    broker.start()
    server = ServerProcess(broker, f"sqlite:///{workdir / 'fleet.db'}", workdir)
    agent = AgentProcess("r1", broker, workdir)
    try:
        server.start()
        agent.start()
        with server.client() as c:
            wait_robot(c, "r1", lambda r: r["online"], timeout=30)
        yield server
        assert server.alive(), server.output()[-3000:]
    finally:
        agent.stop()
        server.stop()
        broker.stop()


def _operations(live: ServerProcess) -> list[schemathesis.APIOperation]:
    schema = schemathesis.openapi.from_url(f"{live.base_url}/openapi.json")
    token = live.token

    @schema.auth()
    class AdminToken:
        """The admin token, as an auth provider rather than a fixed header: in negative mode schemathesis
        then leaves a deliberately invalid Authorization header alone (and expects the 401), where a fixed
        header would silently replace it with the valid token and make the "invalid" request valid."""

        def get(self, case: schemathesis.Case, ctx: schemathesis.AuthContext) -> str:
            return token

        def set(self, case: schemathesis.Case, data: str, ctx: schemathesis.AuthContext) -> None:
            case.headers = {**(case.headers or {}), "Authorization": f"Bearer {data}"}

    return [result.ok() for result in schema.get_all_operations()]


def _answered_by_the_route(response: Any) -> bool:
    """A 401 that the route itself gave (the login's "wrong username or password", code ``bad_credentials``),
    not the authentication layer. Login answers every generated password so; before, it counted as past
    authentication only once a name repeated often enough to be rate-limited (429), which a loaded machine,
    refilling the bucket between slower requests, did not reach."""
    try:
        return response.status_code == 401 and response.json().get("code") == "bad_credentials"
    except ValueError:
        return False


@pytest.mark.slow
@pytest.mark.parametrize("mode", [GenerationMode.POSITIVE, GenerationMode.NEGATIVE])
def test_api_never_fails_with_a_server_error(live: ServerProcess, mode: GenerationMode) -> None:
    """Each operation gets MAX_EXAMPLES generated requests (valid ones, then invalid ones)."""
    failures: list[str] = []
    authorized: set[str] = set()  # operations that got past authentication at least once
    operations = _operations(live)
    assert len(operations) >= 25

    for operation in operations:

        @settings(max_examples=MAX_EXAMPLES, deadline=None, database=None, suppress_health_check=list(HealthCheck))
        @given(case=operation.as_strategy(generation_mode=mode))
        def run(case: schemathesis.Case) -> None:
            if case.query:
                case.query.pop("wait", None)  # long polling: slow, and not what this test is about
            response = case.call_and_validate(
                base_url=live.base_url,
                checks=[not_a_server_error, negative_data_rejection],
                timeout=15,
            )
            if response.status_code not in (401, 403) or _answered_by_the_route(response):
                authorized.add(f"{case.operation.method.upper()} {case.operation.path}")

        try:
            run()
        except Unsatisfiable:
            assert mode is GenerationMode.NEGATIVE  # nothing invalid to send (no parameters, no body)
        except Exception as exc:  # collect every operation's first failure, then report them all
            failures.append(f"{operation.method.upper()} {operation.path}: {str(exc)[:1500]}")
    assert not failures, "\n\n".join(failures)
    if mode is GenerationMode.POSITIVE:  # the auth provider really authenticates every valid request
        everything = {f"{op.method.upper()} {op.path}" for op in operations}
        assert authorized == everything, sorted(everything - authorized)


def test_server_still_healthy_afterwards(live: ServerProcess) -> None:
    r = httpx.get(f"{live.base_url}/api/health", timeout=5)
    assert r.status_code == 200 and r.json()["status"] == "ok"
