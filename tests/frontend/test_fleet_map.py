"""The pool map in Chromium against a real server (its pool outline set by FLEET_POOL_BOUNDARY), broker and
two simulated robots: each robot its own colour (on the map and in the list), the outline from the
setting, a legend, a scale bar, layers switched off and on, labels clear of the heading line, and the selected
robot's pose and speed readout."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator

import pytest

from tests.backend.helpers import wait_robot
from tests.support.procs import ServerProcess

BOUNDARY = [[-3.0, -2.5], [3.5, -2.5], [3.5, 2.5], [-3.0, 2.5]]  # not the simulator's default 4 m x 4 m
ROBOTS = {"map-1": "-1,-0.5,0", "map-2": "1,0.8,1.57"}


@pytest.fixture
def server(broker, database_url, workdir) -> Iterator[ServerProcess]:
    """The page_factory's server, with the pool outline set."""
    s = ServerProcess(broker, database_url, workdir, FLEET_POOL_BOUNDARY=json.dumps(BOUNDARY))
    s.start()
    try:
        yield s
    finally:
        s.stop()


def _robot_pixel_rgb(page, robot_id: str) -> list[int]:
    """The colour of the map's live layer where it drew the robot: where it is drawn and the pixel read in
    one script task (between two, a redraw or a resize of the map, as a late bar above it appears, moves it)."""
    return page.evaluate(
        """(id) => {
      const at = window.fleetDebug.mapRobots()[id];
      const c = document.querySelector('[data-testid=map-live]');
      const k = c.width / c.clientWidth;
      const px = c.getContext('2d').getImageData(Math.round(at.px * k), Math.round(at.py * k), 1, 1).data;
      return Array.from(px).slice(0, 3);
    }""",
        robot_id,
    )


def _css_rgb(page, css: str) -> list[int]:
    return page.evaluate(
        """(css) => {
      const c = document.createElement('canvas'); c.width = c.height = 1;
      const g = c.getContext('2d'); g.fillStyle = css; g.fillRect(0, 0, 1, 1);
      return Array.from(g.getImageData(0, 0, 1, 1).data).slice(0, 3);
    }""",
        css,
    )


def _crosses(seg: list[float], box: dict[str, float]) -> bool:
    x0, y0, x1, y1 = seg
    for i in range(101):
        t = i / 100
        x, y = x0 + (x1 - x0) * t, y0 + (y1 - y0) * t
        if box["x"] <= x <= box["x"] + box["w"] and box["y"] <= y <= box["y"] + box["h"]:
            return True
    return False


def test_map_colours_outline_legend_labels_and_readout(server, spawn_agent, page_factory):
    for rid, pose in ROBOTS.items():
        spawn_agent(rid, f"--start-pose={pose}")
    with server.client() as c:
        for rid in ROBOTS:
            wait_robot(c, rid, lambda r: r["online"] and r["position"], timeout=30)
        assert c.get("/api/site").json()["boundary"] == BOUNDARY
    page, rec = page_factory()
    page.goto("/")
    page.wait_for_function("() => Object.keys(window.fleetDebug?.mapRobots() ?? {}).length === 2", timeout=20000)

    # the outline is the server's setting, and the axes frame it
    outline = page.evaluate("""() => { const t = document.getElementById('fleet-map').data
        .find((d) => d.name === 'pool outline'); return [Array.from(t.x), Array.from(t.y)]; }""")
    ring = [*BOUNDARY, BOUNDARY[0]]
    assert outline == [[p[0] for p in ring], [p[1] for p in ring]]
    xr, yr = page.evaluate(
        "() => { const l = document.getElementById('fleet-map')._fullLayout; return [l.xaxis.range, l.yaxis.range]; }"
    )
    assert xr[0] <= -3.0 and xr[1] >= 3.5 and yr[0] <= -2.5 and yr[1] >= 2.5

    # each robot is drawn in its own colour, the same as its dot in the robot list
    colours = {}
    for rid in ROBOTS:
        expected = page.evaluate("async (id) => (await import('/assets/js/core/robotcolor.js')).robotColor(id)", rid)
        want = _css_rgb(page, expected)
        got = _robot_pixel_rgb(page, rid)
        assert all(abs(a - b) <= 3 for a, b in zip(got, want, strict=True)), (rid, got, want)
        # found and read in one script task, once the row is there: the list renders (and re-renders) every
        # second, and a dot it replaced meanwhile (detached) has no computed style
        dot = page.wait_for_function(
            """(id) => { const e = document.querySelector(`[data-testid=robot-row-${id}] .robot-dot`);
              return e && getComputedStyle(e).backgroundColor; }""",
            arg=rid,
        ).json_value()
        assert _css_rgb(page, dot) == want
        colours[rid] = want
    assert sum(abs(a - b) for a, b in zip(colours["map-1"], colours["map-2"], strict=True)) > 60, colours

    # labels sit clear of the heading line (yaw 0 and yaw 90 degrees)
    labels = page.evaluate("() => window.fleetDebug.mapLabels()")
    for rid in ROBOTS:
        assert labels[rid]["heading"] is not None
        assert not _crosses(labels[rid]["heading"], labels[rid]), (rid, labels[rid])

    legend = page.get_by_test_id("map-legend").inner_text()
    for text in ("base station x axis", "y axis", "base station", "AprilTag seen", "pool outline", "e-stop", "trail"):
        assert text in legend, (text, legend)

    # a scale bar of a round length, and layers switched off and on again (issue 30)
    assert float(page.get_by_test_id("fleet-map").get_attribute("data-scale-m") or 0) in (0.5, 1, 2)
    page.get_by_test_id("map-layers-summary").click()
    for layer in ("site", "stations", "trails", "robots", "goals", "missions"):
        assert page.get_by_test_id(f"map-layer-{layer}").is_checked(), layer
    outline_drawn = "() => document.getElementById('fleet-map').data.some((d) => d.name === 'pool outline')"
    page.get_by_test_id("map-layer-robots").uncheck()
    page.get_by_test_id("map-layer-site").uncheck()
    page.wait_for_function("() => Object.keys(window.fleetDebug.mapRobots()).length === 0")
    page.wait_for_function(f"() => !({outline_drawn})()")
    page.get_by_test_id("map-layer-robots").check()
    page.get_by_test_id("map-layer-site").check()
    page.wait_for_function("() => Object.keys(window.fleetDebug.mapRobots()).length === 2")
    page.wait_for_function(outline_drawn)
    page.get_by_test_id("map-layers-summary").click()

    # the selected robot's readout: its pose, then its speed while it drives
    readout = page.get_by_test_id("map-readout")
    assert "Select a robot" in readout.inner_text()
    page.get_by_test_id("robot-row-map-2").click()
    with server.client() as c:
        pos = c.get("/api/robots/map-2").json()["position"]
    readout.filter(has_text=f"x {pos['x']:.3f} m · y {pos['y']:.3f} m").wait_for()
    assert f"yaw {math.degrees(pos['yaw']):.1f}°" in readout.inner_text()
    assert readout.get_attribute("data-robot") == "map-2"
    # standing still: 0.00 once the page has a speed window of history ("speed —" before that)
    page.wait_for_function(
        "() => document.querySelector('[data-testid=map-readout-speed]').textContent === 'speed 0.00 m/s'",
        timeout=10000,
    )
    with server.client() as c:
        drive = {"command": "move_forward", "args": {"speed": 1, "duration_s": 2}}
        r = c.post("/api/robots/map-2/commands", json=drive)
        assert r.status_code == 202, r.text
    page.wait_for_function(
        """() => {
      const m = document.querySelector('[data-testid=map-readout-speed]').textContent.match(/speed ([0-9.]+)/);
      return m && Number(m[1]) > 0.1; }""",
        timeout=10000,
    )
    page.wait_for_function(
        "() => document.querySelector('[data-testid=map-readout-speed]').textContent === 'speed 0.00 m/s'",
        timeout=10000,
    )  # stopped after its 2 s
    assert rec.console_errors == [], rec.console_errors
