"""The console by role, in a real Chromium: a deep link survives the login, a viewer watches live but cannot
drive (buttons disabled with the reason, keys send nothing) yet may press the E-STOP, and the login page's
?next= never leads off the server."""

from __future__ import annotations

from urllib.parse import parse_qs, urlsplit

import pytest

from tests.backend.helpers import wait_robot
from tests.frontend.console_support import wait_event_handled, watch_event

PASSWORD = "viewer-password-123"


def _log_in(page, username: str, password: str) -> None:
    page.get_by_test_id("login-username").fill(username)
    page.get_by_test_id("login-password").fill(password)
    page.get_by_test_id("login-password").press("Enter")


@pytest.mark.slow
def test_viewer_watches_but_cannot_drive_and_next_stays_local(server, spawn_agent, page_factory):
    spawn_agent("view-1", "--start-pose=0,0,0")
    with server.client() as c:
        r = c.post("/api/users", json={"username": "vic", "password": PASSWORD, "role": "viewer"})
        assert r.status_code == 201, r.text
        start = wait_robot(c, "view-1", lambda r: r["online"] and r["position"] is not None, timeout=30)["position"]
    page, rec = page_factory(logged_in=False)

    # the deep link, query included, is where the login leads back to
    page.goto("/robots/view-1?from=mail")
    page.wait_for_url("**/login?next=*")
    assert parse_qs(urlsplit(page.url).query)["next"] == ["/robots/view-1?from=mail"]
    _log_in(page, "vic", PASSWORD)
    page.wait_for_url("**/robots/view-1?from=mail")
    page.wait_for_function("() => window.fleetDebug?.wsConnected() && window.fleetDebug.me()?.role === 'viewer'")
    assert page.get_by_test_id("robot-title").inner_text() == "view-1"

    # live data, but no driving: every drive button disabled with the reason; keys send nothing
    page.wait_for_function("() => window.fleetDebug.robots()['view-1']?.online === true")
    for testid in ("drive-forward", "drive-backward", "drive-left", "drive-right", "drive-stop"):
        assert page.locator(f"[data-testid={testid}]:visible").is_disabled(), testid
    assert "operator role" in page.locator("[data-testid=drive-reason]:visible").inner_text()
    watch_event(page, "keydown")
    page.keyboard.down("ArrowUp")
    wait_event_handled(page, "keydown")  # the page's key handler has seen it (for an operator it drives at once)
    page.keyboard.up("ArrowUp")
    assert page.evaluate("() => window.fleetDebug.drive().sent") == 0

    # the E-STOP works for a viewer, and the robot's ack shows; releasing is for operators
    page.keyboard.press("Escape")
    page.locator("[data-testid=estop-acks] li.acked[data-robot=view-1]").wait_for(timeout=8000)
    assert page.get_by_test_id("estop-release").is_disabled()
    with server.client() as c:
        assert c.get("/api/estop").json()["acks"] == {"view-1": "done"}
        assert c.post("/api/estop/release", json={"source": "test"}).status_code == 202
        pos = c.get("/api/robots/view-1").json()["position"]
    page.get_by_test_id("estop-bar").wait_for(state="hidden")
    assert (pos["x"], pos["y"]) == (start["x"], start["y"])  # nothing the viewer did moved it

    # ?next= pointing at another host is ignored: a logged-in visit to the login page goes home
    page.goto("/login?next=//example.com/x")
    page.wait_for_url(f"{server.base_url}/")
    page.goto("/login?next=/\\example.com/")
    page.wait_for_url(f"{server.base_url}/")
    hosts = {urlsplit(u).hostname for u in rec.requests if not u.startswith(("data:", "blob:"))}
    assert hosts <= {"127.0.0.1"}, hosts
    assert {f.split()[0] for f in rec.failures} <= {"401"}, rec.failures  # only before logging in
