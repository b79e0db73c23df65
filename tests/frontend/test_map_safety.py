"""The pool map's "Safety distance" layer in Chromium against a real server and broker (issue 31): off at
first, switched on under Layers it draws, around the selected robot, the distance its filter keeps (the site's
min_separation_m, plus the avoidance margin when GET /api/site has one) at the map's scale, in the robot's
colour, and its body; switched off, it is gone."""

from __future__ import annotations

import pytest

from tests.backend.helpers import ProbeRobot, wait_robot

pytestmark = pytest.mark.browser

ROBOT = "safe-1"

# What the live layer holds on a ring around the drawn safety circle's right-most point and halfway in: the
# most opaque pixel of a 5 x 5 patch at each (the stroke is 2 px; anti-aliasing spreads it), read in the same
# script task as where the circle is (a redraw between two tasks may move it).
SAMPLE = """(args) => {
  const [id, fallback] = args;
  const drawn = window.fleetDebug.mapSafety();
  const at = drawn ?? { ...window.fleetDebug.mapRobots()[id], radius_px: fallback };
  const c = document.querySelector('[data-testid=map-live]');
  const k = c.width / c.clientWidth;
  const g = c.getContext('2d');
  const patch = (x, y) => {
    const d = g.getImageData(Math.round(x * k) - 2, Math.round(y * k) - 2, 5, 5).data;
    let best = [0, 0, 0, 0];
    for (let i = 0; i < d.length; i += 4) if (d[i + 3] > best[3]) best = Array.from(d.slice(i, i + 4));
    return best;
  };
  return { drawn, ring: patch(at.px + at.radius_px, at.py), inside: patch(at.px + 0.8 * at.radius_px, at.py) };
}"""


def _rgb(page, css: str) -> list[int]:
    return page.evaluate(
        """(css) => { const c = document.createElement('canvas'); c.width = c.height = 1;
          const g = c.getContext('2d'); g.fillStyle = css; g.fillRect(0, 0, 1, 1);
          return Array.from(g.getImageData(0, 0, 1, 1).data).slice(0, 3); }""",
        css,
    )


def test_the_safety_distance_layer_draws_the_selected_robots_circle(server, mqtt_probe, page_factory):
    robot = ProbeRobot(mqtt_probe, ROBOT)
    robot.status()
    robot.telemetry(0, {"x": 0.5, "y": 0.5, "yaw": 1.5708})  # heading up: its label goes below, the right is clear
    with server.client() as c:
        wait_robot(c, ROBOT, lambda r: r["online"] and r["position"])
        site = c.get("/api/site").json()
    avoidance = site.get("avoidance")  # a server with the safety filter's settings adds their margin
    margin = avoidance["margin_m"] if avoidance and avoidance.get("enabled", True) else 0.0
    expected_m = (site.get("min_separation_m") or 0.3) + margin

    page, rec = page_factory()
    page.goto("/")
    page.wait_for_function("(id) => window.fleetDebug?.mapRobots()[id]", arg=ROBOT, timeout=20000)
    page.get_by_test_id(f"robot-row-{ROBOT}").click()
    page.wait_for_function("(id) => window.fleetDebug.selected() === id", arg=ROBOT)

    # off at first: nothing drawn around the selected robot where the circle would be
    page.get_by_test_id("map-layers-summary").click()
    toggle = page.get_by_test_id("map-layer-safety")
    assert not toggle.is_checked()
    per_metre = page.evaluate("() => window.fleetDebug.mapPoint(1, 0).x - window.fleetDebug.mapPoint(0, 0).x")
    before = page.evaluate(SAMPLE, [ROBOT, expected_m * per_metre])
    assert before["drawn"] is None and before["ring"][3] == 0 and before["inside"][3] == 0, before

    toggle.check()
    page.wait_for_function("() => window.fleetDebug.mapSafety() !== null")
    after = page.evaluate(SAMPLE, [ROBOT, 0])
    drawn = after["drawn"]
    assert drawn["robot"] == ROBOT and drawn["radius_m"] == pytest.approx(expected_m)
    assert drawn["margin_m"] == pytest.approx(margin)
    # at the map's scale (the same projection the robots are placed with), and the body within it
    assert drawn["radius_px"] == pytest.approx(expected_m * per_metre, rel=0.02)
    assert drawn["body_px"] == pytest.approx(0.1 * per_metre, rel=0.02)
    # pixels: the dashed ring in the robot's colour, lightly filled inside
    css = page.evaluate("async (id) => (await import('/assets/js/core/robotcolor.js')).robotColor(id)", ROBOT)
    colour = _rgb(page, css)
    assert after["ring"][3] > 200, after
    assert all(abs(a - b) <= 12 for a, b in zip(after["ring"][:3], colour, strict=True)), (after, colour)
    assert 0 < after["inside"][3] < 80, after

    # switched off (the click's change handler runs in this very task): the next frame draws no circle
    renders = page.evaluate(
        "() => { document.querySelector('[data-testid=map-layer-safety]').click();"
        " return window.fleetDebug.renders(); }"
    )
    assert not toggle.is_checked()
    page.wait_for_function("(n) => window.fleetDebug.renders() > n", arg=renders)
    assert page.evaluate("() => window.fleetDebug.mapSafety()") is None
    gone = page.evaluate(SAMPLE, [ROBOT, drawn["radius_px"]])
    assert gone["ring"][3] == 0 and gone["inside"][3] == 0, gone
    assert not rec.console_errors, rec.console_errors


SEPARATION = {
    "min_separation_m": 0.3,
    "contact_m": 0.2,
    "closest": {"robots": ["m1", "m2"], "distance_m": 0.15, "ts": 1012.5},
    "violations": 1,
    "violation_s": 0.26,
    "contacts": 1,
    "contact_s": 0.13,
    "pairs": [],
    "interventions": 2,
    "intervention_s": 0.4,
    "intervention_min_distance_m": 0.16,
}


def test_the_mission_report_and_the_run_page_say_how_close_the_robots_came(server, mqtt_probe, page_factory):
    ProbeRobot(mqtt_probe, "rep-1").status()
    with server.client() as c:
        wait_robot(c, "rep-1", lambda r: r["online"])
        run = c.post("/api/runs", json={"name": "quiet", "robots": ["rep-1"]}).json()
        assert c.post(f"/api/runs/{run['id']}/stop").status_code == 200
    page, rec = page_factory()
    page.goto("/")
    # the report of an ended mission (the figures as GET /api/missions/{id} gives them)
    lines = page.evaluate(
        """async (sep) => {
          const { missionReport } = await import('/assets/js/missions/missionreport.js');
          const m = { state: 'completed', robots: ['m1', 'm2'], covered_fraction: 1, elapsed_s: 30, started_at: 1000,
            ended_at: 1030, progress: [], run_id: null, separation: sep };
          const host = document.createElement('div');
          host.append(...missionReport(m));
          return [0, 1, 2].map((i) => host.querySelector(`[data-testid=mission-report-separation-${i}]`).textContent);
        }""",
        SEPARATION,
    )
    assert lines == [
        "Closest approach 0.150 m centre to centre (m1 and m2, 12.5 s in).",
        "1 violation (0.26 s) under 0.30 m, 1 contact (0.13 s) under 0.20 m.",
        "2 safety filter interventions (0.40 s, nearest reported 0.160 m).",
    ]
    # a run's page: its summary's figures (one robot: no pair to measure, nothing counted)
    page.goto(f"/runs/{run['id']}")
    fact = page.get_by_test_id("run-separation")
    fact.filter(has_text="0 violations").wait_for()
    assert fact.inner_text() == (
        "closest approach: no two robots measured at the same time; 0 violations (0.00 s) under 0.30 m, "
        "0 contacts (0.00 s) under 0.20 m; 0 safety filter interventions (0.00 s)"
    )
    assert not rec.console_errors, rec.console_errors
