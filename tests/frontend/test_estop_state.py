"""The dashboard's e-stop state follows the newest press or release, whatever order replies arrive in.

While engaged, the page polls ``GET /api/estop`` for the robots' acks. A reply to a poll sent just before a
release can arrive after the WebSocket has said "released"; the page took it, showed the e-stop engaged
again and refused to drive until the next press (seen as a failure of
``tests/frontend/test_stick_drive.py::test_after_an_estop_release_the_stick_must_return_to_centre``). Here the
test holds the page's poll and answers it only after the release.
"""

from __future__ import annotations

import json
from typing import Any

from tests.frontend.console_support import answer_held, wait_held
from tests.support.procs import ServerProcess

ESTOP_GET = "/api/estop"


def _server_state(server: ServerProcess) -> dict[str, Any]:
    """The server's e-stop state now (what a poll sent now would be answered)."""
    with server.client() as c:
        state: dict[str, Any] = c.get(ESTOP_GET).json()
    return state


def test_a_poll_reply_older_than_the_release_does_not_engage_the_page_again(
    server: ServerProcess, page_factory: Any
) -> None:
    page, rec = page_factory()
    held: list[Any] = []
    page.route(
        f"**{ESTOP_GET}",
        lambda route: held.append(route) if route.request.method == "GET" else route.continue_(),
    )
    page.goto("/")
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")

    # a poll's reply is taken while it is the newest state: the bar shows what it says
    with server.client() as c:
        first = c.post("/api/estop", json={"reason": "first", "source": "test"}).json()
    wait_held(page, held, 1, "e-stop polls")
    answer_held(page, held[0], json.dumps({**_server_state(server), "reason": "as the poll said"}), ESTOP_GET)
    page.get_by_test_id("estop-reason").filter(has_text="as the poll said").wait_for()
    assert page.evaluate("() => window.fleetDebug.estop().ts") == first["ts"]
    with server.client() as c:
        c.post("/api/estop/release", json={"source": "test"})
    page.wait_for_function("() => window.fleetDebug.estop().engaged === false")

    # a second press; its poll is answered only after the release, with the state from before the release
    with server.client() as c:
        c.post("/api/estop", json={"reason": "second", "source": "test"})
    wait_held(page, held, 2, "e-stop polls")
    stale = _server_state(server)
    assert stale["engaged"] is True
    with server.client() as c:
        released = c.post("/api/estop/release", json={"source": "test"}).json()
    assert released["ts"] > stale["ts"]
    page.wait_for_function("() => window.fleetDebug.estop().engaged === false")
    answer_held(page, held[1], json.dumps(stale), ESTOP_GET)
    assert page.evaluate("() => window.fleetDebug.estop().engaged") is False
    assert page.get_by_test_id("estop-release").is_hidden()
    assert page.get_by_test_id("estop").inner_text() == "E-STOP"
    assert not rec.console_errors, rec.console_errors
