"""Go-to on the fleet map in Chromium (issue 17, Dashboard): a click on the map sends the selected robot
to the clicked point only while Go-to is armed; the map shows the running goal; a refused goal says why
inline; the site (boundary, keep-outs, wall tags) is drawn, and "no site: no fence" when there is none.
Real server, broker and simulated agent (water current, noise and latency on: --disturbances)."""

from __future__ import annotations

import math
import time

import orjson
import pytest

from tests.frontend.console_support import axe_violations, open_page, wait_event_handled, watch_event
from tests.frontend.motion_support import position, publish_site, select, start_robot, stored
from tests.support.procs import wait_for

RID = "goer-1"
START = "-1,-0.8,0"
TOLERANCE_M = 0.05  # the goal tolerance the page sends (frontend/js/drive/goto.js)


@pytest.fixture
def robot(server, mqtt_probe, spawn_agent):
    publish_site(mqtt_probe)
    return start_robot(server, spawn_agent, RID, START, "--disturbances")


def _click_map_at(page, x: float, y: float, shift: bool = False) -> None:
    at = page.evaluate("([x, y]) => window.fleetDebug.mapPoint(x, y)", [x, y])
    assert at is not None, "the map is not laid out"
    if shift:
        page.keyboard.down("Shift")
    page.mouse.click(at["x"], at["y"])
    if shift:
        page.keyboard.up("Shift")


def _goto_commands(server) -> list[dict]:
    with server.client() as c:
        return [cmd for cmd in c.get(f"/api/robots/{RID}/commands").json() if cmd["command"] == "goto"]


def _final(server, cid: str, timeout: float = 60) -> dict:
    def done() -> dict | None:
        with server.client() as c:
            cmd = c.get(f"/api/commands/{cid}").json()
        return cmd if cmd["status"] in ("done", "failed", "aborted", "rejected", "expired") else None

    return wait_for(done, timeout, interval=0.2, what=f"command {cid} final")


def _open_selected(page_factory):
    page, rec = open_page(page_factory, "/")
    select(page, RID)
    page.wait_for_function(f"() => window.fleetDebug.mapRobots()['{RID}']")
    return page, rec


def test_click_to_go_moves_the_robot_to_the_clicked_point(server, robot, page_factory):
    page, rec = _open_selected(page_factory)
    target = (-0.4, -0.3)
    page.get_by_test_id("goto-toggle").click()
    assert page.get_by_test_id("goto-toggle").get_attribute("aria-pressed") == "true"
    _click_map_at(page, *target)
    page.wait_for_function("() => window.fleetDebug.goto().goal || window.fleetDebug.goto().result")
    sent = page.evaluate("() => window.fleetDebug.goto()")
    assert not sent["error"], sent
    cid = sent["goal"]["id"] if sent["goal"] else None
    assert cid, sent
    goal = _goto_commands(server)[0]["args"]
    # the page sends what was clicked: the pixel under the cursor, in metres (a pixel is under a centimetre)
    assert math.hypot(goal["x"] - target[0], goal["y"] - target[1]) < 0.02, goal
    # while it runs, the map shows the goal, the distance left and a Cancel button
    page.get_by_test_id("goto-cancel").wait_for(state="visible")
    page.wait_for_function(  # from the robot's motion stream
        "() => /\\d\\.\\d\\d m to go/.test(document.querySelector('[data-testid=goto-status]').textContent)"
    )
    assert page.evaluate("() => window.fleetDebug.goto().active.id") == cid
    final = _final(server, cid)
    assert final["status"] == "done", final
    done_at = max(a["ts"] for a in final["acks"] if a["status"] == "done")
    # measured from the stored positions: the samples of the last 0.15 s before the robot said done (the
    # mean of three or so, as the simulated Lighthouse is noisy)
    pts = [p["data"] for p in stored(server, RID, "position", done_at - 0.15) if p["ts"] <= done_at]
    assert pts, "no stored positions before done"
    x = sum(p["x"] for p in pts) / len(pts)
    y = sum(p["y"] for p in pts) / len(pts)
    print(f"goal ({goal['x']:.3f}, {goal['y']:.3f}); robot at done ({x:.3f}, {y:.3f})")
    assert math.hypot(x - goal["x"], y - goal["y"]) <= TOLERANCE_M
    page.wait_for_function("() => window.fleetDebug.goto().result?.status === 'done'")
    assert "goal reached" in page.get_by_test_id("goto-result").inner_text()
    assert page.get_by_test_id("goto-cancel").is_hidden()
    assert axe_violations(page) == []
    assert not rec.console_errors, rec.console_errors


def test_a_click_with_go_to_off_does_not_move_the_robot(server, robot, page_factory):
    page, _ = _open_selected(page_factory)
    # first prove that a click in Go-to mode moves it (Shift+click: the momentary arm)
    first = (-0.7, -0.5)
    _click_map_at(page, *first, shift=True)
    page.wait_for_function("() => window.fleetDebug.goto().goal || window.fleetDebug.goto().result")
    cid = page.evaluate("() => window.fleetDebug.goto().goal?.id")
    assert cid and _final(server, cid)["status"] == "done"
    assert page.get_by_test_id("goto-toggle").get_attribute("aria-pressed") == "false"  # never armed
    before = position(server, RID)
    # now plain clicks, far from the robot (not on its marker), with Go-to off
    watch_event(page, "click")
    _click_map_at(page, 1.2, 1.2)
    _click_map_at(page, -1.5, 1.5)
    wait_event_handled(page, "click", 2)
    time.sleep(1.5)  # the behaviour under test is "nothing happens": give a goal time to have been sent
    assert page.evaluate("() => window.fleetDebug.goto().sent") == 1
    assert len(_goto_commands(server)) == 1
    after = position(server, RID)
    # the current pushes an idle robot by a few cm at most in this time; a goal would have moved it > 1 m
    assert math.hypot(after["x"] - before["x"], after["y"] - before["y"]) < 0.1, (before, after)


def test_a_path_is_drawn_and_sent_with_a_double_click(server, robot, page_factory):
    page, _ = _open_selected(page_factory)
    page.get_by_test_id("path-toggle").click()
    page.wait_for_function("() => document.getElementById('fleet-map')._context.doubleClick === false")
    points = [(-0.8, -0.3), (-0.3, -0.3)]
    _click_map_at(page, *points[0])
    at = page.evaluate("([x, y]) => window.fleetDebug.mapPoint(x, y)", list(points[1]))
    page.mouse.dblclick(at["x"], at["y"])
    page.wait_for_function("() => window.fleetDebug.goto().goal || window.fleetDebug.goto().result")
    with server.client() as c:
        cmds = [x for x in c.get(f"/api/robots/{RID}/commands").json() if x["command"] == "follow_path"]
    assert len(cmds) == 1
    waypoints = cmds[0]["args"]["waypoints"]
    assert len(waypoints) == 2, waypoints  # the double click's own clicks add no extra point
    for (x, y), (wx, wy) in zip(points, waypoints, strict=True):
        assert math.hypot(x - wx, y - wy) < 0.02
    page.get_by_test_id("goto-cancel").wait_for(state="visible")
    page.get_by_test_id("goto-cancel").click()
    final = _final(server, cmds[0]["id"])
    assert final["status"] == "aborted", final
    page.wait_for_function("() => window.fleetDebug.goto().result?.status === 'aborted'")


def test_a_goal_outside_the_fence_is_refused_and_the_reason_shows_inline(server, robot, page_factory):
    page, _ = _open_selected(page_factory)
    page.get_by_test_id("goto-toggle").click()
    _click_map_at(page, -2.15, 0.0)  # inside the plot, outside the pool boundary
    page.wait_for_function("() => window.fleetDebug.goto().result || window.fleetDebug.goto().error")
    result = page.get_by_test_id("goto-result")
    assert "geofence" in result.inner_text(), result.inner_text()
    assert result.is_visible()


SITE = {
    "version": 7,
    "site": {
        "boundary": [[-2, -2], [2, -2], [2, 2], [-2, 2]],
        "keepouts": [[[0.5, 0.5], [1.0, 0.5], [1.0, 1.0], [0.5, 1.0]]],
        "tags": [{"id": 3, "size_m": 0.1, "pose": {"x": -2.0, "y": 0.5, "z": 0.2, "yaw": 0.0}}, {"id": 4}],
    },
}


@pytest.mark.parametrize("reply", [SITE, {"version": 8, "site": None}], ids=["site", "no-site"])
def test_the_site_is_drawn_or_no_site_is_said(server, page_factory, reply):
    page, _ = page_factory()
    page.route(
        "**/api/site",
        lambda route: route.fulfill(status=200, body=orjson.dumps(reply), content_type="application/json"),
    )
    page.goto("/")
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.mapSite() !== undefined")
    status = page.get_by_test_id("site-status").inner_text()
    traces = page.evaluate(
        "() => Object.fromEntries(document.getElementById('fleet-map').data.map(t => [t.name, "
        "{x: t.x, y: t.y, text: t.text}]))"
    )
    if reply["site"] is None:
        assert "no site: no fence" in status
        assert [v for v in traces["pool outline"]["x"] if v is not None] == []
        return
    summary = page.get_by_test_id("site-status").get_attribute("title")
    assert "1 keep-out" in summary and "1 wall tag" in summary, summary  # the tag without a pose is skipped
    assert "pool outline" in status
    legend = page.get_by_test_id("map-legend").inner_text()
    assert "keep-out" in legend and "wall tag" in legend, legend
    assert [v for v in traces["keep-outs"]["x"] if v is not None] == [0.5, 1.0, 1.0, 0.5, 0.5]
    assert traces["site tags"]["text"] == ["T3"] and traces["site tags"]["x"] == [-2.0]
    assert len([v for v in traces["pool outline"]["x"] if v is not None]) == 5
