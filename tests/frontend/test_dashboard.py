"""The operator's console in a real Chromium against a real server, broker and three simulated robots."""

from __future__ import annotations

import math
import time
from typing import Any
from urllib.parse import urlsplit

from tests.frontend.conftest import FLEET, SCREENSHOTS
from tests.frontend.console_support import wait_event_handled, wait_frames, watch_event
from tests.support.procs import wait_for

PLOTTED = """() => {
  const out = {};
  for (const [id, d] of Object.entries(window.fleetDebug?.mapRobots?.() ?? {})) out[id] = [d.x, d.y];
  return out;
}"""
# how many pixels around each robot's drawn position the live map layer painted (not transparent)
PAINTED = """() => {
  const c = document.querySelector('[data-testid=map-live]');
  const dpr = c.width / c.clientWidth;
  const ctx = c.getContext('2d');
  const out = {};
  for (const [id, d] of Object.entries(window.fleetDebug.mapRobots())) {
    const px = ctx.getImageData(Math.round((d.px - 4) * dpr), Math.round((d.py - 4) * dpr), 8, 8).data;
    let n = 0;
    for (let i = 3; i < px.length; i += 4) if (px[i] > 200) n++;
    out[id] = n;
  }
  return out;
}"""


def _robot(server, rid: str) -> dict[str, Any]:
    with server.client() as c:
        return c.get(f"/api/robots/{rid}").json()


def _still(server, rid: str) -> dict[str, Any]:
    """The robot's position once it stopped moving (fresh telemetry, unchanged over 0.4 s)."""

    def check() -> dict[str, Any] | None:
        a = _robot(server, rid)["position"]
        time.sleep(0.4)  # the stillness window is the definition of "standing still", not a wait for an event
        b = _robot(server, rid)["position"]
        return b if b["ts"] > a["ts"] and math.hypot(b["x"] - a["x"], b["y"] - a["y"]) < 1e-4 else None

    return wait_for(check, 10, what=f"{rid} standing still")


def _visible(page, testid: str):
    """The visible element with this test id (the fleet and robot pages each have a drive pad)."""
    return page.locator(f"[data-testid={testid}]:visible")


def _open(page_factory, path: str = "/"):
    page, rec = page_factory()
    page.goto(path)
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    return page, rec


def test_fleet_view_shows_every_robot_live(server, fleet, page_factory):
    page, rec = _open(page_factory)
    for rid in FLEET:
        row = page.get_by_test_id(f"robot-row-{rid}")
        row.wait_for()
        assert row.get_attribute("data-online") == "true"
    page.wait_for_function(f"() => Object.keys(({PLOTTED})()).length === {len(FLEET)}")
    plotted = page.evaluate(PLOTTED)
    for rid, pose in FLEET.items():
        x, y, _ = (float(v) for v in pose.split(","))
        assert math.hypot(plotted[rid][0] - x, plotted[rid][1] - y) < 0.05, (rid, plotted[rid])
    # each robot is painted on the live layer where the map says it is
    painted = page.evaluate(PAINTED)
    assert all(painted[rid] >= 20 for rid in FLEET), painted
    # the Plotly layer: one WebGL trace per kind of static thing, never one per robot
    names = page.evaluate("() => document.getElementById('fleet-map').data.map((d) => d.name)")
    assert sorted(names) == ["base stations", "bs-x", "bs-y", "keep-outs", "pool outline", "site tags", "tags"], names
    assert page.evaluate("() => window.fleetDebug.renders()") > 0
    # a click on a robot's marker selects it (and the hover tip names it)
    box = page.get_by_test_id("fleet-map").bounding_box()
    at = page.evaluate("() => window.fleetDebug.mapRobots()")["snail-3"]
    page.mouse.move(box["x"] + at["px"], box["y"] + at["py"])
    page.wait_for_function("() => !document.querySelector('.map-tip').hidden")
    assert page.locator(".map-tip").inner_text().startswith("snail-3")
    page.mouse.click(box["x"] + at["px"], box["y"] + at["py"])
    page.wait_for_function("() => window.fleetDebug.selected() === 'snail-3'")
    # the Lighthouse base stations, published once (retained) before this page opened, are drawn
    page.wait_for_function(
        "() => document.getElementById('fleet-map').data.find((d) => d.name === 'base stations').x.length >= 2"
    )
    wait_frames(page)  # the map's redraw of what arrived is on screen for the picture
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.get_by_test_id("robot-row-snail-2").click()
    page.screenshot(path=str(SCREENSHOTS / "dashboard.png"))
    hosts = {urlsplit(u).hostname for u in rec.requests if not u.startswith(("data:", "blob:"))}
    assert hosts <= {"127.0.0.1", "localhost"}, hosts
    assert rec.failures == [], rec.failures
    assert rec.console_errors == [], rec.console_errors


def test_hold_button_drives_and_release_stops(server, fleet, page_factory):
    page, _ = _open(page_factory)
    page.get_by_test_id("robot-row-snail-1").click()
    page.wait_for_function("() => window.fleetDebug.selected() === 'snail-1'")
    start = _still(server, "snail-1")
    plotted_start = page.evaluate(PLOTTED)["snail-1"]
    button = _visible(page, "drive-forward")
    assert button.is_enabled()
    box = button.bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.wait_for_timeout(1500)  # holding the button for a while is the behaviour under test
    moving = _robot(server, "snail-1")["position"]
    page.mouse.up()
    assert math.hypot(moving["x"] - start["x"], moving["y"] - start["y"]) > 0.1, (start, moving)
    assert moving["x"] > start["x"]  # yaw 0: forward is +x
    stopped = _still(server, "snail-1")
    # released: stopped within the half-second deadman at most (0.3 m/s x 0.5 s plus the lag)
    assert math.hypot(stopped["x"] - moving["x"], stopped["y"] - moving["y"]) < 0.25
    page.wait_for_function(f"() => Math.abs(({PLOTTED})()['snail-1'][0] - {stopped['x']}) < 0.01", timeout=5000)
    assert page.evaluate(PLOTTED)["snail-1"][0] - plotted_start[0] > 0.1
    sources = {c["source"] for c in page.evaluate("() => window.fleetDebug.commands()")}
    assert "ui-button" in sources
    page.get_by_test_id("command-log").locator("li[data-command='move_forward']").first.wait_for()
    # the other robots never moved
    other = _robot(server, "snail-3")["position"]
    assert math.hypot(other["x"] - 1.2, other["y"] + 1) < 1e-3
    # sliding off the button while still pressing stops the robot too
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.wait_for_function("() => window.fleetDebug.drive().active?.command === 'move_forward'")
    wait_for(lambda: _robot(server, "snail-1")["position"]["x"] > stopped["x"] + 0.02, 5, what="driving again")
    page.mouse.move(box["x"] - 150, box["y"] + 200, steps=4)
    assert page.evaluate("() => window.fleetDebug.drive().active") is None
    slid = _still(server, "snail-1")  # still with the mouse button down
    page.mouse.up()
    assert slid["x"] > stopped["x"] + 0.02


def test_keyboard_turns_while_held_and_space_stops(server, fleet, page_factory):
    page, _ = _open(page_factory)
    page.get_by_test_id("robot-row-snail-2").click()
    page.wait_for_function("() => window.fleetDebug.selected() === 'snail-2'")
    yaw0 = _still(server, "snail-2")["yaw"]
    page.keyboard.down("ArrowLeft")
    page.wait_for_timeout(1000)  # holding the key for a while is the behaviour under test
    page.keyboard.up("ArrowLeft")
    yaw1 = _still(server, "snail-2")["yaw"]
    turned = math.atan2(math.sin(yaw1 - yaw0), math.cos(yaw1 - yaw0))  # yaw wraps at +-pi
    assert turned > 0.3, (yaw0, yaw1)  # turned left (counter-clockwise)
    page.keyboard.down("w")
    page.wait_for_timeout(600)  # holding the key for a while is the behaviour under test
    pressed_at = time.time()
    page.keyboard.press(" ")  # space = stop at once, even while w is still down
    page.wait_for_function(  # the robot has the stop
        f"() => window.fleetDebug.commands().some((c) => c.command === 'stop' && c.ts >= {pressed_at - 0.05}"
        " && c.acks.length > 0)"
    )
    after_space = _robot(server, "snail-2")["position"]
    page.keyboard.up("w")
    stopped = _still(server, "snail-2")
    assert math.hypot(stopped["x"] - after_space["x"], stopped["y"] - after_space["y"]) < 0.05
    # typing in a text field never drives
    page.get_by_test_id("robot-filter").focus()
    watch_event(page, "keydown")
    page.keyboard.down("ArrowUp")
    wait_event_handled(page, "keydown")  # the page's key handler has seen it (outside a text field it drives at once)
    page.keyboard.up("ArrowUp")
    assert page.evaluate("() => window.fleetDebug.drive().active") is None


def test_estop_stops_every_robot_and_release_restores_driving(server, fleet, page_factory):
    page, _ = _open(page_factory)
    with server.client() as c:
        for rid in FLEET:
            body = {"command": "move_forward", "args": {"speed": 1, "duration_s": 5}}
            r = c.post(f"/api/robots/{rid}/commands", json=body)
            assert r.status_code == 202
            wait_for(
                lambda r=r: c.get(f"/api/commands/{r.json()['id']}").json()["status"] == "accepted",
                5,
                what="the robot driving",
            )
    page.keyboard.press("Escape")  # Esc = e-stop, from anywhere on the page
    status = page.get_by_test_id("estop-status")
    page.wait_for_function(
        "() => document.querySelector('[data-testid=estop-status]').textContent.includes('3/3')", timeout=5000
    )
    assert "ENGAGED" in status.inner_text()
    page.locator("[data-testid=events] li[data-kind=estop]").first.wait_for(timeout=8000)  # in the timeline
    positions = {rid: _still(server, rid) for rid in FLEET}
    for rid in FLEET:
        assert _robot(server, rid)["estop"] is True
    with server.client() as c:
        state = c.get("/api/estop").json()
    assert state["engaged"] and set(state["acks"]) == set(FLEET), state
    for rid in FLEET:  # each robot's ack is on screen
        page.locator(f"[data-testid=estop-acks] li.acked[data-robot={rid}]").wait_for()
    # a drive command while engaged is refused by the server (409 naming the e-stop and who pressed it: it
    # never reaches the robot, which would refuse it too) and nothing moves
    with server.client() as c:
        body = {"command": "move_forward", "args": {"speed": 1, "duration_s": 1}, "source": "test"}
        r = c.post("/api/robots/snail-2/commands", params={"wait": 3}, json=body)
    assert r.status_code == 409 and "e-stop engaged by browser-admin" in r.json()["detail"], r.text
    after = _still(server, "snail-2")
    assert math.hypot(after["x"] - positions["snail-2"]["x"], after["y"] - positions["snail-2"]["y"]) < 1e-3
    page.get_by_test_id("robot-row-snail-3").click()
    assert _visible(page, "drive-forward").is_disabled()
    assert "E-stop" in _visible(page, "drive-reason").inner_text()
    page.get_by_test_id("estop-release").click()  # arms: a second press within 4 s releases
    assert page.get_by_test_id("estop-release").inner_text() == "Tap again to release"
    with server.client() as c:
        assert c.get("/api/estop").json()["engaged"] is True  # one press released nothing
    page.get_by_test_id("estop-release").click()
    page.wait_for_function("() => !window.fleetDebug.estop().engaged")
    wait_for(lambda: not _robot(server, "snail-3")["estop"], 5, what="release reaches the robot")
    # the script that drove the robots above (another caller) still holds snail-3's control lease: the
    # page says so; once the script lets go, the operator at the page drives
    assert "Driven by" in _visible(page, "drive-reason").inner_text()
    with server.client() as c:
        assert c.delete("/api/robots/snail-3/lease").status_code == 204
    _visible(page, "drive-forward").and_(page.locator(":enabled")).wait_for()
    button = _visible(page, "drive-forward")
    button.hover()
    page.mouse.down()
    page.wait_for_timeout(800)  # holding the button for a while is the behaviour under test
    page.mouse.up()
    moved = _still(server, "snail-3")
    assert math.hypot(moved["x"] - positions["snail-3"]["x"], moved["y"] - positions["snail-3"]["y"]) > 0.05
