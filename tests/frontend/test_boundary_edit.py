"""Editing the site's boundary on the fleet map in Chromium (issue 17, Dashboard): an admin drags, adds and
removes corners (mouse and keyboard) and saves a new site version that GET /api/site serves, keep-outs and
tags kept; a self-intersecting boundary gets the server's 422 inline and changes nothing; Cancel and Esc drop
the draft (Esc still presses the E-STOP); while editing, map clicks and arrow keys on a handle move no robot;
viewers and operators have no edit control. Real server, broker and (for Go-to) a simulated agent."""

from __future__ import annotations

import math
from typing import Any

from tests.backend.api.conftest import new_token
from tests.frontend.console_support import axe_violations, open_page, wait_event_handled, wait_frames, watch_event
from tests.frontend.motion_support import publish_site, select, start_robot

POOL = [[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]
KEEPOUT = [[-0.5, -0.5], [0.0, -0.5], [0.0, 0.0], [-0.5, 0.0]]
TAGS = [{"id": 3, "size_m": 0.1, "pose": {"x": 2.0, "y": 0.0, "z": 0.1, "yaw": 3.14159}}]
#: a pixel of the map is under a centimetre: a dragged corner lands this close to where the mouse let go
PIXEL_M = 0.02


def _site(server) -> dict[str, Any]:
    with server.client() as c:
        return c.get("/api/site").json()  # type: ignore[no-any-return]


def _put_site(server, **site: Any) -> dict[str, Any]:
    with server.client() as c:
        r = c.put("/api/site", json=site)
        assert r.status_code == 200, r.text
        return r.json()  # type: ignore[no-any-return]


def _state(page) -> dict[str, Any]:
    return page.evaluate("() => window.fleetDebug.boundaryEdit()")  # type: ignore[no-any-return]


def _start_editing(page, version: int) -> None:
    page.wait_for_function(f"() => window.fleetDebug.mapSite()?.version === {version}")
    page.wait_for_function("() => document.querySelector('#fleet-map .main-svg')")
    page.get_by_role("button", name="Edit boundary").click()
    page.wait_for_function("() => window.fleetDebug.boundaryEdit().active")
    _wait_placed(page)


def _wait_placed(page) -> None:
    """Until every handle sits where its corner is on the map (the live layer placed them)."""
    page.wait_for_function(
        """() => { const s = window.fleetDebug.boundaryEdit();
          return s.draft.every(([x, y], i) => {
            const h = document.querySelector(`[data-testid=boundary-corner-${i}]`);
            if (!h || h.hidden) return false;
            const r = h.getBoundingClientRect(), at = window.fleetDebug.mapPoint(x, y);
            return Math.hypot(r.x + r.width / 2 - at.x, r.y + r.height / 2 - at.y) < 1.5;
          }); }"""
    )


def _drag(page, testid: str, x: float, y: float) -> None:
    """Mouse: press on the handle, move in steps to the map point (x, y), let go."""
    box = page.get_by_test_id(testid).bounding_box()
    to = page.evaluate("([x, y]) => window.fleetDebug.mapPoint(x, y)", [x, y])
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.mouse.move(to["x"], to["y"], steps=8)
    page.mouse.up()
    _wait_placed(page)


def _near(p: list[float], q: tuple[float, float]) -> bool:
    return math.hypot(p[0] - q[0], p[1] - q[1]) < PIXEL_M


def _outline_xs(page) -> list[float]:
    return page.evaluate(  # type: ignore[no-any-return]
        "() => Array.from(document.getElementById('fleet-map').data.find((d) => d.name === 'pool outline').x)"
    )


def test_an_admin_drags_a_corner_and_saves_a_new_version_keeping_keepouts_and_tags(server, page_factory):
    before = _put_site(server, boundary=POOL, keepouts=[KEEPOUT], tags=TAGS, geofence_margin_m=0.2)
    page, rec = open_page(page_factory, "/")
    _start_editing(page, before["version"])
    assert page.get_by_test_id("boundary-save").is_visible() and page.get_by_test_id("boundary-cancel").is_visible()
    assert axe_violations(page) == [], "editing the boundary"  # the handles are named buttons

    target = (-1.6, -1.7)
    _drag(page, "boundary-corner-0", *target)
    draft = _state(page)["draft"]
    assert _near(draft[0], target), draft
    assert draft[1:] == POOL[1:], draft
    assert _site(server)["version"] == before["version"]  # a preview only, until Save

    page.get_by_test_id("boundary-save").click()
    version = before["version"] + 1
    page.wait_for_function(f"() => window.fleetDebug.mapSite()?.version === {version}")
    assert not _state(page)["active"] and page.get_by_test_id("boundary-corner-0").count() == 0
    assert page.get_by_test_id("boundary-error").inner_text() == ""
    site = _site(server)
    assert site["version"] == version and site["source"] == "api"
    assert site["boundary"] == [draft[0], *POOL[1:]]  # the moved corner, as the page showed it
    assert site["keepouts"] == [KEEPOUT] and site["tags"] == TAGS and site["geofence_margin_m"] == 0.2
    # the map draws the new outline; the Edit site form shows the new version too
    page.wait_for_function(
        """(x0) => Array.from(document.getElementById('fleet-map').data
          .find((d) => d.name === 'pool outline').x)[0] === x0""",
        arg=draft[0][0],
    )
    page.get_by_test_id("site-line").filter(has_text=f"Site v{version}").wait_for()
    assert rec.console_errors == [], rec.console_errors


def test_an_admin_adds_and_removes_corners_with_the_mouse_and_the_keyboard(server, page_factory):
    before = _site(server)
    assert before["boundary"] == POOL
    page, rec = open_page(page_factory, "/")
    _start_editing(page, before["version"])

    # the "+" on the edge from corner 2 to corner 3 adds a corner at its middle; a drag moves it out
    page.get_by_test_id("boundary-add-1").click()
    page.wait_for_function("() => window.fleetDebug.boundaryEdit().draft.length === 5")
    assert _state(page)["draft"][2] == [2.0, 0.0]
    _wait_placed(page)
    _drag(page, "boundary-corner-2", 2.2, 0.1)
    bulge = _state(page)["draft"][2]
    assert _near(bulge, (2.2, 0.1)), bulge
    # a double click removes a corner
    page.get_by_test_id("boundary-corner-0").dblclick()
    page.wait_for_function("() => window.fleetDebug.boundaryEdit().draft.length === 4")
    assert _state(page)["draft"] == [POOL[1], bulge, POOL[2], POOL[3]]
    _wait_placed(page)

    # keyboard: arrows move the focused corner (1 cm, Shift 10 cm); Enter on a "+" adds one, Delete removes it
    page.get_by_test_id("boundary-corner-3").focus()
    page.keyboard.press("ArrowRight")
    page.keyboard.press("ArrowRight")
    page.keyboard.press("Shift+ArrowDown")
    moved = [POOL[1], bulge, POOL[2], [-1.98, 1.9]]
    assert _state(page)["draft"] == moved
    page.get_by_test_id("boundary-add-0").focus()
    page.keyboard.press("Enter")
    page.wait_for_function("() => window.fleetDebug.boundaryEdit().draft.length === 5")
    assert page.evaluate("() => document.activeElement.dataset.testid") == "boundary-corner-1"
    page.keyboard.press("Delete")
    page.wait_for_function("() => window.fleetDebug.boundaryEdit().draft.length === 4")
    assert _state(page)["draft"] == moved

    # Remove corner (the selected one); a boundary keeps three corners
    _wait_placed(page)
    page.get_by_test_id("boundary-corner-1").click()
    page.get_by_role("button", name="Remove corner 2").click()
    page.wait_for_function("() => window.fleetDebug.boundaryEdit().draft.length === 3")
    triangle = [POOL[1], POOL[2], [-1.98, 1.9]]
    assert _state(page)["draft"] == triangle
    assert page.get_by_test_id("boundary-remove").is_disabled()

    page.get_by_test_id("boundary-save").click()
    page.wait_for_function(f"() => window.fleetDebug.mapSite()?.version === {before['version'] + 1}")
    site = _site(server)
    assert site["version"] == before["version"] + 1 and site["boundary"] == triangle
    assert rec.console_errors == [], rec.console_errors


def test_a_self_intersecting_boundary_gets_the_servers_422_and_changes_nothing(server, page_factory):
    before = _site(server)
    page, rec = open_page(page_factory, "/")
    _start_editing(page, before["version"])
    # corner 1 dragged past the right wall: the edge from corner 4 crosses the right wall's edge
    _drag(page, "boundary-corner-0", 2.2, 0.0)
    page.get_by_test_id("boundary-hint").filter(has_text="crosses itself").wait_for()
    page.get_by_test_id("boundary-save").click()
    error = page.get_by_test_id("boundary-error")
    error.filter(has_text="bad_polygon").wait_for()
    assert "boundary is not a simple polygon" in error.inner_text() and "unchanged" in error.inner_text()
    assert _site(server)["version"] == before["version"] and _site(server)["boundary"] == POOL
    state = _state(page)
    assert state["active"] and _near(state["draft"][0], (2.2, 0.0)), state  # the draft stays for a fix
    assert _outline_xs(page) == [p[0] for p in [*POOL, POOL[0]]]  # the map still draws the site in force

    # Cancel drops the draft: the handles go, nothing was sent
    page.get_by_test_id("boundary-cancel").click()
    page.wait_for_function("() => !window.fleetDebug.boundaryEdit().active")
    assert page.get_by_test_id("boundary-corner-0").count() == 0
    assert _site(server)["version"] == before["version"]

    # after a refusal, a fixed boundary saves (the refusal was the polygon's, not the page's)
    _start_editing(page, before["version"])
    _drag(page, "boundary-corner-0", 2.2, 0.0)
    page.get_by_test_id("boundary-save").click()
    error.filter(has_text="bad_polygon").wait_for()
    _drag(page, "boundary-corner-0", -1.5, -1.5)
    page.get_by_test_id("boundary-save").click()
    version = before["version"] + 1
    page.wait_for_function(f"() => window.fleetDebug.mapSite()?.version === {version}")
    assert _near(_site(server)["boundary"][0], (-1.5, -1.5))

    # Esc drops an edit too; it still presses the fleet E-STOP, as everywhere on the page
    _start_editing(page, version)
    _drag(page, "boundary-corner-1", 1.5, -1.5)
    page.keyboard.press("Escape")
    page.wait_for_function("() => !window.fleetDebug.boundaryEdit().active")
    page.wait_for_function("() => window.fleetDebug.estop().engaged")
    assert _site(server)["version"] == version and _site(server)["boundary"][1] == POOL[1]
    with server.client() as c:
        assert c.post("/api/estop/release", json={"source": "test"}).is_success
    # the two refused PUTs are the browser's own log lines; nothing else went wrong
    assert [e for e in rec.console_errors if "status of 422" not in e] == [], rec.console_errors
    assert len(rec.console_errors) == 2, rec.console_errors


def test_a_finger_drags_a_corner_on_a_touch_tablet(server, page_factory):
    before = _site(server)
    page, rec = open_page(page_factory, "/", "tablet")
    _start_editing(page, before["version"])
    box = page.get_by_test_id("boundary-corner-2").bounding_box()
    start = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    to = page.evaluate("() => window.fleetDebug.mapPoint(1.5, 1.6)")
    cdp = page.context.new_cdp_session(page)  # real touch input (pointerType "touch"), not synthetic events

    def touch(kind: str, x: float, y: float) -> None:
        points = [] if kind == "touchEnd" else [{"x": x, "y": y, "id": 1}]
        cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": points})

    touch("touchStart", *start)
    for i in range(1, 9):
        touch("touchMove", start[0] + (to["x"] - start[0]) * i / 8, start[1] + (to["y"] - start[1]) * i / 8)
    touch("touchEnd", *to.values())
    _wait_placed(page)
    draft = _state(page)["draft"]
    assert _near(draft[2], (1.5, 1.6)) and draft[:2] == POOL[:2] and draft[3] == POOL[3], draft
    page.get_by_test_id("boundary-save").click()
    page.wait_for_function(f"() => window.fleetDebug.mapSite()?.version === {before['version'] + 1}")
    assert _site(server)["boundary"][2] == draft[2]
    assert rec.console_errors == [], rec.console_errors


def test_viewers_and_operators_have_no_edit_control(server, page_factory, browser):
    admin, _ = open_page(page_factory, "/")
    admin.get_by_test_id("boundary-edit").wait_for(state="visible")  # the control exists, for admins
    for role in ("viewer", "operator"):
        token = new_token(server, role)
        ctx = browser.new_context(base_url=server.base_url, extra_http_headers={"Authorization": f"Bearer {token}"})
        try:
            page = ctx.new_page()
            page.goto("/")
            page.wait_for_function(f"() => window.fleetDebug?.me()?.role === '{role}'")
            page.wait_for_function("() => window.fleetDebug.mapSite()")
            assert page.get_by_test_id("boundary-edit").is_hidden(), role
            assert page.get_by_role("button", name="Edit boundary").count() == 0, role
        finally:
            ctx.close()


RID = "edge-1"


def test_while_editing_map_clicks_and_handle_keys_move_no_robot(server, mqtt_probe, spawn_agent, page_factory):
    publish_site(mqtt_probe)
    start_robot(server, spawn_agent, RID, "-1,-0.8,0")
    page, rec = open_page(page_factory, "/")
    select(page, RID)
    _start_editing(page, _site(server)["version"])
    assert page.get_by_test_id("goto-toggle").is_disabled() and page.get_by_test_id("path-toggle").is_disabled()

    # Shift+click (Go-to's momentary arm) on the map while editing: no goal, the robot stays selected
    watch_event(page, "click")
    at = page.evaluate("() => window.fleetDebug.mapPoint(0.5, 0.5)")
    page.keyboard.down("Shift")
    page.mouse.click(at["x"], at["y"])
    page.keyboard.up("Shift")
    wait_event_handled(page, "click")
    assert page.evaluate("() => window.fleetDebug.goto().sent") == 0
    assert page.evaluate("() => window.fleetDebug.selected()") == RID
    # an arrow key on a focused corner moves the corner, not the robot
    page.get_by_test_id("boundary-corner-0").focus()
    page.keyboard.press("ArrowUp")
    assert _state(page)["draft"][0] == [-2.0, -1.99]
    wait_frames(page)
    assert page.evaluate("() => window.fleetDebug.drive().sent") == 0

    # after Cancel the same click sends the goal and the same key drives: they could have happened above
    page.get_by_test_id("boundary-cancel").click()
    page.wait_for_function("() => !window.fleetDebug.boundaryEdit().active")
    assert page.get_by_test_id("goto-toggle").is_enabled()
    page.keyboard.down("Shift")
    page.mouse.click(at["x"], at["y"])
    page.keyboard.up("Shift")
    page.wait_for_function("() => window.fleetDebug.goto().sent === 1")
    page.locator("body").focus()
    page.evaluate("() => document.activeElement.blur()")
    page.keyboard.press("ArrowUp")
    page.wait_for_function("() => window.fleetDebug.drive().sent > 0")
    assert _site(server)["boundary"] == POOL  # nothing was saved
    assert rec.console_errors == [], rec.console_errors
