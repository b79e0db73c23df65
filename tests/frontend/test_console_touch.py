"""The console on a phone (390x844) and a tablet (820x1180) with touch (issue 21, items 1 and 4): the
E-STOP and Release lie fully inside the viewport, whatever the scroll, and work with a tap (measured on the
server and on the robots); the navigation folds behind a menu on the phone; the map and the drive pad fit
together; a tap on a robot on the map selects it; reasons show inline, not as hover tooltips."""

from __future__ import annotations

import pytest

from tests.backend.helpers import wait_robot
from tests.frontend.conftest import FLEET
from tests.frontend.console_support import (
    inside_viewport,
    no_horizontal_overflow,
    open_page,
    wait_event_handled,
    watch_event,
)
from tests.support.procs import wait_for

ESTOP = "[data-testid=estop]"
#: where a robot's marker is on screen (client pixels), and whether the map is what a finger there touches
ROBOT_ON_SCREEN_JS = """(rid) => { const m = document.querySelector('#fleet-map'); const r = m.getBoundingClientRect();
  const d = window.fleetDebug.mapRobots()[rid]; const x = r.left + d.px, y = r.top + d.py;
  const top = document.elementFromPoint(x, y);
  return {x, y, onMap: !!top && m.contains(top), topmost: top ? top.tagName + '.' + top.className : null}; }"""
RELEASE = "[data-testid=estop-release]"


def _engaged(server) -> dict:
    with server.client() as c:
        return c.get("/api/estop").json()


def _robots_stopped(server, stopped: bool) -> bool:
    with server.client() as c:
        return all(c.get(f"/api/robots/{rid}").json()["estop"] is stopped for rid in FLEET)


@pytest.mark.parametrize("device", ["phone", "tablet"])
def test_estop_and_release_are_in_reach_and_work_with_a_tap(server, fleet, page_factory, device):
    page, rec = open_page(page_factory, "/", device)
    page.get_by_test_id("robot-row-snail-1").wait_for()
    assert page.evaluate("() => matchMedia('(pointer: coarse)').matches")  # really a touch device
    no_horizontal_overflow(page)
    inside_viewport(page, ESTOP)
    if device == "phone":
        # the navigation is folded away; the menu button opens it
        assert page.get_by_role("link", name="History").is_hidden()
        page.get_by_test_id("nav-toggle").tap()
        inside_viewport(page, "nav a[data-nav=history]")
        page.get_by_test_id("nav-toggle").tap()
        assert page.get_by_role("link", name="History").is_hidden()
        # a full-width bar: the E-STOP takes most of the width at the bottom edge
        box = inside_viewport(page, ESTOP)
        assert box["w"] >= 0.7 * box["vw"] and box["bottom"] >= box["vh"] - 20, box
    # the map and the whole drive pad are on screen together, none of it under the e-stop dock
    dock_top = page.evaluate("() => document.querySelector('[data-testid=estop-dock]').getBoundingClientRect().top")
    inside_viewport(page, "#fleet-map")
    for testid in ("drive-forward", "drive-backward", "drive-left", "drive-right", "drive-stop"):
        box = inside_viewport(page, f"#drive-host [data-testid={testid}]")
        if device == "phone":
            assert box["bottom"] <= dock_top, (testid, box, dock_top)
    # scrolled to the very end, the E-STOP is still in reach
    page.evaluate("() => window.scrollTo(0, document.documentElement.scrollHeight)")
    page.wait_for_function("() => window.scrollY > 0 || document.documentElement.scrollHeight <= innerHeight")
    inside_viewport(page, ESTOP)

    page.locator(ESTOP).tap()
    wait_for(lambda: _engaged(server)["engaged"], 5, what="the e-stop engaged on the server")
    wait_for(lambda: _robots_stopped(server, True), 8, what="every robot reporting its e-stop latched")
    page.locator(RELEASE).wait_for()
    no_horizontal_overflow(page)
    inside_viewport(page, RELEASE)
    inside_viewport(page, ESTOP)
    assert "latched" in page.locator(ESTOP).get_attribute("class")
    # one tap only arms the release (it says so, inline); nothing is released yet
    page.locator(RELEASE).tap()
    assert page.locator(RELEASE).inner_text() == "Tap again to release"
    assert _engaged(server)["engaged"] is True
    inside_viewport(page, RELEASE)
    page.locator(RELEASE).tap()
    wait_for(lambda: not _engaged(server)["engaged"], 5, what="the e-stop released on the server")
    wait_for(lambda: _robots_stopped(server, False), 8, what="every robot reporting its e-stop released")
    page.locator(RELEASE).wait_for(state="hidden")
    assert rec.console_errors == [], rec.console_errors


@pytest.mark.parametrize("device", ["phone", "tablet"])
def test_a_tap_on_a_robot_on_the_map_selects_it(server, fleet, page_factory, device):
    page, _ = open_page(page_factory, "/", device)
    page.wait_for_function(f"() => Object.keys(window.fleetDebug.mapRobots()).length === {len(FLEET)}")
    assert page.evaluate("() => window.fleetDebug.selected()") is None
    for rid in ("snail-3", "snail-1"):
        # the map's box and the robot's drawn place in one read (the map can be laid out again between two)
        at = page.evaluate(ROBOT_ON_SCREEN_JS, rid)
        assert at["onMap"], f"{rid}'s marker is under {at['topmost']}, not the map: {at}"
        page.touchscreen.tap(at["x"], at["y"])
        try:
            page.wait_for_function(f"() => window.fleetDebug.selected() === '{rid}'", timeout=10_000)
        except Exception as e:  # say what the map made of the tap
            seen = page.evaluate(f"() => [window.fleetDebug.mapLastTap(), ({ROBOT_ON_SCREEN_JS})('{rid}')]")
            what = f"tap at {at} did not select {rid}; the map's last tap, and the robot now: {seen}"
            raise AssertionError(what) from e
        page.wait_for_function(
            f"() => document.querySelector('#drive-host [data-testid=drive-target]').textContent === '{rid}'"
        )
    # a tap on empty water selects nothing new
    box = page.locator("#fleet-map").bounding_box()
    watch_event(page, "pointerup")
    page.touchscreen.tap(box["x"] + box["width"] / 2, box["y"] + 20)
    wait_event_handled(page, "pointerup")  # the map's tap handler (it selects on pointerup) has run
    assert page.evaluate("() => window.fleetDebug.selected()") == "snail-1"


def test_reasons_show_inline_on_touch(server, fleet, page_factory, spawn_agent, tmp_path):
    """A viewer on a phone: why the drive pad and Release are disabled is on screen, not in a tooltip."""
    config = tmp_path / "snail-9.toml"
    config.write_text('extra_commands = ["set_speed"]\n')
    spawn_agent("snail-9", "--config", str(config))
    with server.client() as c:
        r = c.post("/api/users", json={"username": "vera", "password": "viewer-password-1", "role": "viewer"})
        assert r.status_code == 201, r.text
    page, _ = page_factory(390, 844, logged_in=False, has_touch=True, is_mobile=True)
    page.goto("/login")
    page.get_by_test_id("login-username").fill("vera")
    page.get_by_test_id("login-password").fill("viewer-password-1")
    page.get_by_test_id("login-password").press("Enter")
    page.wait_for_function("() => window.fleetDebug?.wsConnected() && window.fleetDebug.me()?.role === 'viewer'")
    page.get_by_test_id("robot-row-snail-2").tap()
    page.wait_for_function("() => window.fleetDebug.selected() === 'snail-2'")
    reason = page.locator("#drive-host [data-testid=drive-reason]")
    assert "operator role" in reason.inner_text() and reason.is_visible()
    page.locator(ESTOP).tap()  # viewers may stop the fleet ...
    page.locator(RELEASE).wait_for()
    assert page.locator(RELEASE).is_disabled()  # ... not release it, and the bar says why
    note = page.get_by_test_id("estop-release-note")
    assert note.is_visible() and "operator role" in note.inner_text()
    # a command the robot refuses: its reason is in its row of the command log, not only in a title (drives
    # are refused by the server while the e-stop is latched, so this is a robot-specific command with args
    # only the robot checks)
    with server.client() as c:
        c.post("/api/estop/release", json={"source": "test"})
        wait_robot(c, "snail-9", lambda r: r["online"], timeout=30)
        r = c.post(
            "/api/robots/snail-9/commands",
            params={"wait": 3},
            json={"command": "set_speed", "args": {"speed": 7}, "source": "test"},
        )
        assert r.json()["status"] == "rejected", r.text
        cid, reason_text = r.json()["id"], r.json()["reason"]
    row = page.locator(f"#log-host li[data-id='{cid}']")
    # the row can come first as "sent" (the command's own event) and take its ack a moment later: wait for
    # the ack's reason in it, not just for the row (read as "sent" once on a loaded machine)
    assert reason_text
    row.filter(has_text=reason_text).wait_for()
    assert reason_text in row.inner_text()
