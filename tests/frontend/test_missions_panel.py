"""The missions panel in Chromium: draw an area on its map, pick two robots, preview the plan, Start, see the
coverage layer grow (from the robots' actual tracks), Abort; the robots stop and the mission says aborted.
The fleet map's mission panel: state, covered %, Pause / Resume / Abort, without moving the page's layout."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest

from tests.frontend.console_support import axe_violations, inside_viewport, open_page, wait_boxes_settled
from tests.support.missions import publish_site, wait_ready
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, ServerProcess

AREA = [(-0.6, -0.5), (0.6, -0.5), (0.6, 0.5), (-0.6, 0.5)]


def covered(page: Any) -> float:
    return float(page.get_by_test_id("mission-status").get_attribute("data-covered") or 0)


def click_pool(page: Any, x: float, y: float) -> None:
    """Click the missions page's map at (x, y) in metres (the map's own projection, once it is drawn)."""
    page.wait_for_function("([x, y]) => window.fleetDebug.missionsAt(x, y) !== null", arg=[x, y])
    at = page.evaluate("([x, y]) => window.fleetDebug.missionsAt(x, y)", [x, y])
    page.mouse.click(at["x"], at["y"])


def map_data(page: Any, key: str) -> int:
    """A count the missions page's map holds (data-mission-area, -paths, -swept)."""
    return int(page.get_by_test_id("mission-map").get_attribute(f"data-mission-{key}") or 0)


#: the pool map's axes as Plotly laid them out, and its scale in pixels per metre on each axis
AXES_JS = """(id) => { const fl = document.getElementById(id)._fullLayout;
  const scale = (a) => a._length / (a.range[1] - a.range[0]);
  return {titles: [fl.xaxis.title.text, fl.yaxis.title.text], x: fl.xaxis.range, y: fl.yaxis.range,
          kx: scale(fl.xaxis), ky: scale(fl.yaxis),
          canvas: !!document.querySelector(`#${id} [data-testid=map-live]`)}; }"""


def test_draw_start_watch_coverage_abort(
    server: ServerProcess,
    spawn_agent: Callable[..., AgentProcess],
    mqtt_probe: Callable[..., MqttProbe],
    page_factory: Callable[..., tuple[Any, Any]],
) -> None:
    """The missions page is a workplace on the fleet page's own map: draw the area, pick the robots, preview,
    start, watch the swept area and each robot's share fill in (pushed: the page asks for nothing while it
    runs), abort; the mission is in the list with its state and its run, and the run links back to it."""
    publish_site(mqtt_probe())
    spawn_agent("w1", "--disturbances", "--start-pose=-0.45,-0.4,1.57")
    spawn_agent("w2", "--disturbances", "--start-pose=0.15,-0.4,1.57")
    with server.client() as c:
        wait_ready(c, ["w1", "w2"])
    page, rec = page_factory(1280, 900)
    page.goto("/")
    page.wait_for_function("() => document.querySelector('#fleet-map .main-svg')")
    page.get_by_test_id("nav-missions").click()
    page.get_by_test_id("mission-robot-w2").wait_for()
    for x, y in AREA:
        click_pool(page, x, y)
    assert map_data(page, "area") == 4
    page.get_by_test_id("mission-robot-w1").check()
    page.get_by_test_id("mission-robot-w2").check()
    page.get_by_test_id("mission-width").fill("0.25")
    page.get_by_test_id("mission-plan").click()
    page.wait_for_function("() => document.querySelector('[data-testid=mission-map]').dataset.missionPaths === '2'")
    page.wait_for_function("() => document.querySelector('[data-testid=mission-status]').dataset.state === 'draft'")
    assert map_data(page, "area") == 0  # the drawing became the plan
    with server.client() as c:
        mission = c.get("/api/missions").json()[0]
        area = c.get(f"/api/missions/{mission['id']}").json()["params"]["area"]
    assert page.url.endswith(f"/missions/{mission['id']}")
    # the drawn corners went to the server as the area (to the map's pixel, rounded to 1 cm)
    assert all(abs(p[0] - q[0]) <= 0.02 and abs(p[1] - q[1]) <= 0.02 for p, q in zip(area, AREA, strict=True)), area
    # the same map component as the fleet page's: its axes in metres, equal on both axes, its live layer
    fleet, missions = page.evaluate(AXES_JS, "fleet-map"), page.evaluate(AXES_JS, "missions-map")
    assert fleet["titles"] == missions["titles"] == ["x (m)", "y (m)"] and fleet["canvas"] and missions["canvas"]
    for axes in (fleet, missions):
        assert abs(axes["kx"] - axes["ky"]) < 1e-6 * axes["kx"], axes  # one metre is as long on both axes
        assert axes["x"][0] < -2 < 2 < axes["x"][1] and axes["y"][0] < -2 < 2 < axes["y"][1], axes  # the pool
    page.get_by_test_id(f"mission-row-{mission['id']}").wait_for()
    asked_before_start = len(rec.requests)
    page.get_by_test_id("mission-start").click()
    page.wait_for_function("() => document.querySelector('[data-testid=mission-status]').dataset.state === 'running'")
    page.wait_for_function(
        "() => Number(document.querySelector('[data-testid=mission-status]').dataset.covered) > 0.05", timeout=60_000
    )
    first = covered(page)
    # the swept area, pushed once it changed (looked at every second): drawn on the map
    page.wait_for_function("() => document.querySelector('[data-testid=mission-map]').dataset.missionSwept !== '0'")
    deadline = time.time() + 60
    while covered(page) <= first + 0.05:
        assert time.time() < deadline, f"coverage stuck at {covered(page)}"
        page.wait_for_timeout(500)
    assert page.locator("[data-testid=mission-shares] li").count() == 2  # each robot's share
    assert page.get_by_test_id(f"mission-row-{mission['id']}").get_attribute("data-state") == "running"
    page.get_by_test_id("mission-abort").click()
    page.wait_for_function("() => document.querySelector('[data-testid=mission-status]').dataset.state === 'aborted'")
    with server.client() as c:
        m = c.get(f"/api/missions/{mission['id']}").json()
    assert m["state"] == "aborted" and [t["to_state"] for t in m["transitions"]] == ["draft", "running", "aborted"]
    assert all(p["status"] in ("stopped", "done") for p in m["progress"]), m["progress"]
    # while it ran the page asked the missions' routes for nothing: the start and the abort, then the report
    # read once
    asked = [u.split("/api/", 1)[1] for u in rec.requests[asked_before_start:] if "/api/missions" in u]
    mid = mission["id"]
    assert asked[:2] == [f"missions/{mid}/start", f"missions/{mid}/abort"], asked
    assert set(asked[2:]) <= {f"missions/{mid}", f"missions/{mid}/coverage"}, asked
    # the report, and the run it links to, which links back
    page.get_by_test_id("mission-report").wait_for()
    assert "aborted" in page.get_by_test_id("mission-report-summary").inner_text()
    assert page.get_by_test_id(f"mission-row-{mid}").get_attribute("data-state") == "aborted"
    assert m["run_id"] is not None
    page.get_by_test_id("mission-report-run").click()
    page.get_by_test_id("run-mission").get_by_role("link").wait_for()
    assert page.url.endswith(f"/runs/{m['run_id']}")
    page.get_by_test_id("run-mission").get_by_role("link").click()
    page.wait_for_function("() => document.querySelector('[data-testid=mission-status]').dataset.state === 'aborted'")
    assert page.url.endswith(f"/missions/{mid}")
    with server.client() as c:
        assert c.get(f"/api/runs/{m['run_id']}").json()["mission_id"] == mid
    assert axe_violations(page) == []
    assert not rec.console_errors, rec.console_errors


LAYOUT_JS = """() => { const box = (sel) => { const r = document.querySelector(sel).getBoundingClientRect();
    return [Math.round(r.x), Math.round(r.y), Math.round(r.width), Math.round(r.height)]; };
  // the map panel and the map (the panel's only neighbours in its flow), and where the side panel starts (its
  // height, and so the list's place under it on a phone, follows its own content: the mission's commands)
  return {mapPanel: box('.fleet-view .map-panel'), map: box('#fleet-map'),
          sideTop: box('.fleet-view .side-panel').slice(0, 2)}; }"""


@pytest.mark.parametrize("device", [None, "phone"])
def test_the_fleet_map_panel_shows_the_mission_and_acts_without_moving_the_layout(
    server: ServerProcess,
    spawn_agent: Callable[..., AgentProcess],
    mqtt_probe: Callable[..., MqttProbe],
    page_factory: Callable[..., tuple[Any, Any]],
    device: str | None,
) -> None:
    """The fleet page's mission panel floats over the map: hidden with no mission, then state and covered %
    while one runs, Pause / Resume / Abort acting on the server, axe clean open and closed, and the page's
    panels exactly where they were before it appeared and after it opened (desktop and phone). The fleet map
    draws the mission's plan and its swept area, and all of it comes pushed on the live socket: the page
    never asks for a mission (issue 30)."""
    publish_site(mqtt_probe())
    spawn_agent("ov1", "--disturbances", "--start-pose=-0.4,-0.4,1.57")
    with server.client() as c:
        wait_ready(c, ["ov1"])
    page, rec = open_page(page_factory, "/", device)
    page.get_by_test_id("robot-row-ov1").wait_for()
    page.wait_for_function("() => document.querySelector('#fleet-map .main-svg')")
    overlay = page.get_by_test_id("mission-overlay")
    wait_boxes_settled(page, [".fleet-view .map-panel", "#fleet-map", ".fleet-view .side-panel"])
    before = page.evaluate(LAYOUT_JS)
    assert overlay.is_hidden()
    with server.client() as c:
        area = [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]
        body = {"type": "coverage", "robots": ["ov1"], "params": {"area": area, "sweep_width_m": 0.25}}
        mid = c.post("/api/missions", json=body).json()["id"]
        assert c.post(f"/api/missions/{mid}/start").status_code == 200
    page.locator("[data-testid=mission-overlay][data-state=running]").wait_for(timeout=15000)
    # the plan came with the mission's own push: it is on the map as soon as the panel says running
    assert page.evaluate("() => Number(document.getElementById('fleet-map').dataset.missionPaths)") == 1
    assert page.evaluate(LAYOUT_JS) == before, "the panel moved the page's layout"
    over, under = overlay.bounding_box(), page.locator("#fleet-map").bounding_box()
    assert over and under and over["height"] > 0, over  # it is there, floating over the map's corner
    assert under["x"] <= over["x"] and over["x"] + over["width"] <= under["x"] + under["width"], (over, under)
    assert under["y"] <= over["y"] < under["y"] + under["height"] / 2, (over, under)
    assert "running" in page.get_by_test_id("mission-overlay-summary").inner_text()
    inside_viewport(page, "[data-testid=mission-overlay-summary]")
    assert axe_violations(page) == [], "mission panel closed"
    page.get_by_test_id("mission-overlay-summary").click()
    page.get_by_test_id("mission-overlay-pause").wait_for()
    assert page.evaluate(LAYOUT_JS) == before, "opening the panel moved the page's layout"
    inside_viewport(page, "[data-testid=mission-overlay-abort]")
    assert axe_violations(page) == [], "mission panel open"
    page.wait_for_function(
        "() => Number(document.querySelector('[data-testid=mission-overlay]').dataset.covered) > 0", timeout=60_000
    )
    # the swept area (mission_coverage) is drawn from the server's geometry
    page.wait_for_function("() => Number(document.getElementById('fleet-map').dataset.missionSwept) > 0")
    page.get_by_test_id("mission-overlay-pause").click()
    page.locator("[data-testid=mission-overlay][data-state=paused]").wait_for(timeout=15000)
    page.get_by_test_id("mission-overlay-resume").click()
    page.locator("[data-testid=mission-overlay][data-state=running]").wait_for(timeout=15000)
    page.get_by_test_id("mission-overlay-abort").click()
    page.locator("[data-testid=mission-overlay][data-state=aborted]").wait_for(timeout=15000)
    assert page.get_by_test_id("mission-overlay-abort").is_disabled()
    with server.client() as c:
        m = c.get(f"/api/missions/{mid}").json()
    assert [t["to_state"] for t in m["transitions"]] == ["draft", "running", "paused", "running", "aborted"]
    assert page.evaluate(LAYOUT_JS) == before
    assert not rec.console_errors, rec.console_errors
    # nothing polled: the page only sent the three actions (the panel's buttons) to the missions' routes
    asked = [u.split("/api/missions", 1)[1] for u in rec.requests if "/api/missions" in u]
    assert asked == [f"/{mid}/pause", f"/{mid}/resume", f"/{mid}/abort"], asked
    # an aborted mission leaves the map (its final state stays in the panel)
    page.wait_for_function("() => document.getElementById('fleet-map').dataset.missionPaths === '0'")


@pytest.mark.slow
def test_a_formation_from_the_missions_page_follows_the_clicked_path(
    server: ServerProcess,
    spawn_agent: Callable[..., AgentProcess],
    mqtt_probe: Callable[..., MqttProbe],
    page_factory: Callable[..., tuple[Any, Any]],
) -> None:
    """Formation on the Missions page: the clicked points are the leader's path, the other robots take slots in
    a V behind it at the chosen spacing; Start, and the mission runs to the path's end with its followers
    travelling along (the formation's quality is measured in
    tests/backend/services/missions/test_missions_formation.py)."""
    publish_site(mqtt_probe())
    starts = {"fl-1": (-0.6, 0.0), "fl-2": (-1.1, 0.5), "fl-3": (-1.1, -0.5)}
    for rid, (x, y) in starts.items():
        spawn_agent(rid, "--disturbances", f"--start-pose={x},{y},0")
    with server.client() as c:
        wait_ready(c, list(starts))
    page, rec = page_factory(1280, 900)
    page.goto("/missions")
    page.get_by_test_id("mission-robot-fl-3").wait_for()
    page.get_by_test_id("mission-type").select_option("formation")
    assert page.get_by_test_id("mission-width").is_hidden() and page.get_by_test_id("mission-spacing").is_visible()
    for x, y in [(-0.6, 0.0), (0.6, 0.0)]:
        click_pool(page, x, y)
    for rid in starts:
        page.get_by_test_id(f"mission-robot-{rid}").check()
    assert page.get_by_test_id("mission-leader").input_value() == "fl-1"  # the first picked leads
    page.get_by_test_id("mission-spacing").fill("0.5")
    page.get_by_test_id("mission-loop").uncheck()
    page.get_by_test_id("mission-plan").click()
    status = page.get_by_test_id("mission-status")
    page.wait_for_function("() => document.querySelector('[data-testid=mission-status]').dataset.state === 'draft'")
    with server.client() as c:
        mission = c.get(f"/api/missions/{c.get('/api/missions').json()[0]['id']}").json()
    params = mission["params"]
    assert mission["type"] == "formation" and params["leader"] == "fl-1" and params["loop"] is False, mission
    assert params["slots"] == {"fl-2": [-0.5, 0.5], "fl-3": [-0.5, -0.5]}, params["slots"]
    assert all(
        abs(p[0] - q[0]) <= 0.02 and abs(p[1] - q[1]) <= 0.02
        for p, q in zip(params["path"], [(-0.6, 0), (0.6, 0)], strict=True)
    )
    page.get_by_test_id("mission-start").click()
    page.wait_for_function(
        "() => ['completed', 'failed', 'aborted', 'paused'].includes("
        "document.querySelector('[data-testid=mission-status]').dataset.state)",
        timeout=90_000,
    )
    assert status.get_attribute("data-state") == "completed", status.inner_text()
    with server.client() as c:
        robots = {r["id"]: r["position"] for r in c.get("/api/robots").json() if r["id"] in starts}
    for rid, (x, _) in starts.items():  # everyone travelled along +x with the leader
        assert robots[rid]["x"] - x > 0.6, (rid, robots[rid])
    assert axe_violations(page) == []
    assert not rec.console_errors, rec.console_errors
