"""Rehearse on the missions page in Chromium (issue 32): a small coverage mission drawn on the map, rehearsed in
the server's twin of the fleet; the predicted tracks drawn on the map (one dotted line per robot, in its
colour), the figures shown; one rehearsal at a time (a double press sends one, a second one of the same user is
refused and the page says why); a second Rehearse replaces the tracks, another mission opened removes them;
after the real run the report sets the prediction beside the outcome. On a phone the buttons stay where they
were while it runs and when the figures come, and Close removes the tracks."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from decimal import ROUND_HALF_UP, Decimal
from typing import Any

from tests.frontend.console_support import (
    axe_violations,
    boxes,
    open_page,
    wait_boxes_settled,
    wait_frames,
    wait_held,
)
from tests.support.missions import publish_site, wait_ready
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, ServerProcess

#: a 1.2 x 1.0 m area, three robots on its lower edge, swept 0.3 m wide
AREA = [(-0.6, -0.5), (0.6, -0.5), (0.6, 0.5), (-0.6, 0.5)]
ROBOTS = {"rh1": "-0.45,-0.4,1.57", "rh2": "0,-0.4,1.57", "rh3": "0.45,-0.4,1.57"}
#: the live canvas of the missions page's map: how many of its pixels hold any paint
PAINTED_JS = """() => { const cv = document.querySelector('#missions-map [data-testid=map-live]');
  const d = cv.getContext('2d').getImageData(0, 0, cv.width, cv.height).data;
  let n = 0; for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++; return n; }"""


def coverage_body(robots: list[str]) -> dict[str, Any]:
    """A draft coverage mission of AREA, as POST /api/missions takes it."""
    return {"type": "coverage", "robots": robots, "params": {"area": [list(p) for p in AREA], "sweep_width_m": 0.3}}


def start_fleet(spawn_agent: Callable[..., AgentProcess], mqtt_probe: Callable[..., MqttProbe], server: Any) -> None:
    publish_site(mqtt_probe())
    for rid, pose in ROBOTS.items():
        spawn_agent(rid, f"--start-pose={pose}")
    with server.client() as c:
        wait_ready(c, list(ROBOTS))


def click_pool(page: Any, x: float, y: float) -> None:
    """Click the missions page's map at (x, y) in metres (the map's own projection, once it is drawn)."""
    page.wait_for_function("([x, y]) => window.fleetDebug.missionsAt(x, y) !== null", arg=[x, y])
    at = page.evaluate("([x, y]) => window.fleetDebug.missionsAt(x, y)", [x, y])
    page.mouse.click(at["x"], at["y"])


def tracks_on_map(page: Any) -> int:
    return int(page.get_by_test_id("mission-map").get_attribute("data-predicted-tracks") or 0)


def wait_block(page: Any, state: str) -> None:
    page.locator(f"[data-testid=rehearsal][data-state={state}]").wait_for(timeout=30_000)


def figures(page: Any) -> dict[str, str]:
    """The rehearsal's figures as shown: {key: text}."""
    rows = page.locator("[data-testid=rehearsal] [data-testid=rehearsal-figures] tr")
    return {r.get_attribute("data-figure"): r.locator("td").inner_text() for r in rows.all()}


def js_round(x: float) -> int:
    """Math.round (halves up; Python's round() takes halves to even: 44.5 s would read 45 s, not 44 s)."""
    return math.floor(x + 0.5)


def js_fixed(x: float, digits: int) -> str:
    """Number.prototype.toFixed: the exact binary value, a tie to the larger (Python's format: to even)."""
    return str(Decimal(x).quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP))


def hue(css: str) -> float:
    return float(re.match(r"hsla?\(([\d.]+)", css).group(1))  # type: ignore[union-attr]


def rehearsals_asked(rec: Any) -> int:
    return sum(1 for u in rec.requests if u.endswith("/rehearsal"))


def test_rehearse_draws_the_predicted_tracks_and_figures_then_sets_them_beside_the_outcome(
    server: ServerProcess,
    spawn_agent: Callable[..., AgentProcess],
    mqtt_probe: Callable[..., MqttProbe],
    page_factory: Callable[..., tuple[Any, Any]],
) -> None:
    start_fleet(spawn_agent, mqtt_probe, server)
    page, rec = open_page(page_factory, "/missions", width=1280, height=900)
    page.get_by_test_id("mission-robot-rh3").wait_for()
    rehearse = page.get_by_test_id("mission-rehearse")
    assert rehearse.is_disabled()  # no mission opened yet
    for x, y in AREA:
        click_pool(page, x, y)
    for rid in ROBOTS:
        page.get_by_test_id(f"mission-robot-{rid}").check()
    page.get_by_test_id("mission-width").fill("0.3")
    page.get_by_test_id("mission-plan").click()
    page.wait_for_function("() => document.querySelector('[data-testid=mission-status]').dataset.state === 'draft'")
    mid = page.url.rsplit("/", 1)[1]
    assert rehearse.is_enabled() and rehearse.inner_text() == "Rehearse"

    # one rehearsal at a time per user: one started by the same user from elsewhere (here: a fetch of the
    # page's own) makes the button's refused, and the page says why as text, where its other refusals go
    page.evaluate("(id) => { window.__other = fetch(`/api/missions/${id}/rehearsal`, {method: 'POST'}); }", mid)
    page.wait_for_timeout(500)  # it reached the server: a rehearsal takes seconds (its process starts first)
    rehearse.click()
    error = page.get_by_test_id("mission-error")
    page.wait_for_function("() => document.querySelector('[data-testid=mission-error]').textContent.includes('time')")
    assert error.inner_text().startswith("Refused: a rehearsal of yours is running"), error.inner_text()
    assert page.evaluate("async () => (await window.__other).status") == 200
    # that rehearsal's summary, kept with the mission and pushed: its figures, no tracks
    wait_block(page, "kept")
    assert "Latest rehearsal" in page.get_by_test_id("rehearsal-title").text_content()
    assert tracks_on_map(page) == 0

    # a double press sends one rehearsal: the button is busy and disabled at once. Its answer is held while the
    # busy page is read (a rehearsal of this small mission can take under a second: the answer once came first)
    asked = rehearsals_asked(rec)
    held: list[Any] = []
    page.route("**/rehearsal", lambda route: held.append(route))
    rehearse.dblclick()
    wait_held(page, held, 1, "rehearsals")
    assert page.evaluate("() => window.fleetDebug.rehearsal().busy")
    assert rehearse.is_disabled() and rehearse.get_attribute("aria-busy") == "true"
    assert "Rehearsing" in page.get_by_test_id("rehearsal-title").text_content()
    with page.expect_response(lambda r: r.url.endswith("/rehearsal")) as answered:
        held[0].continue_()
    first = answered.value.json()
    page.unroute("**/rehearsal")
    assert len(held) == 1 and rehearsals_asked(rec) == asked + 1, "the busy button sent a second rehearsal"
    wait_block(page, "drawn")
    assert error.inner_text() == ""
    assert rehearse.is_enabled() and rehearse.get_attribute("aria-busy") == "false"

    # the layer: one track per robot, drawn in the robot's own colour (lighter), and on the canvas
    tracks = {f["properties"]["robot_id"] for f in first["predicted"]["tracks"]["features"]}
    assert tracks == set(ROBOTS), tracks
    assert tracks_on_map(page) == 3
    page.wait_for_function("() => window.fleetDebug.rehearsal().drawn.length === 3")
    debug = page.evaluate("() => window.fleetDebug.rehearsal()")
    colours = {t["robotId"]: t["color"] for t in debug["tracks"]}
    for drawn in debug["drawn"]:
        assert drawn["color"].startswith("hsla(") and hue(drawn["color"]) == hue(colours[drawn["robotId"]]), drawn
        assert drawn["points"] >= 2
    with_tracks = page.evaluate(PAINTED_JS)
    page.locator("#missions-map").get_by_test_id("map-layers-summary").click()
    page.locator("#missions-map").get_by_test_id("map-layer-predicted").uncheck()
    wait_frames(page)
    without = page.evaluate(PAINTED_JS)
    page.locator("#missions-map").get_by_test_id("map-layer-predicted").check()
    page.locator("#missions-map").get_by_test_id("map-layers-summary").click()
    assert with_tracks - without > 300, (with_tracks, without)  # the dotted lines and their end rings

    # the figures, as the server answered them
    p = first["predicted"]
    shown = figures(page)
    assert shown["duration_s"].startswith(f"{js_round(p['duration_s'])} s"), shown
    assert shown["covered_fraction"] == f"{js_fixed(p['covered_fraction'] * 100, 1)}%", shown
    assert shown["min_separation_m"].startswith(f"{js_fixed(p['min_separation_m'], 3)} m"), shown
    for key in ("filter_interventions", "blocked_legs", "fence_violations"):
        assert shown[key].startswith(str(p[key])), (key, shown)
    assert shown["collisions"] == str(p["collisions"]), shown
    speed = page.get_by_test_id("rehearsal-speed").inner_text()
    simulated = rf"seed {first['seed']} · simulated {js_round(p['duration_s'])} s in [\d.]+ s, \u00d7\d+"
    assert re.fullmatch(simulated, speed), speed
    legend = page.locator("[data-testid=rehearsal-legend] li")
    assert sorted(li.get_attribute("data-robot") for li in legend.all()) == sorted(ROBOTS)

    # a second Rehearse replaces the tracks (still one per robot), and its figures
    with page.expect_response(lambda r: r.url.endswith("/rehearsal")) as answered:
        rehearse.click()
    second = answered.value.json()
    page.wait_for_function("(seed) => window.fleetDebug.rehearsal().seed === seed", arg=second["seed"])
    assert second["seed"] != first["seed"] and tracks_on_map(page) == 3
    assert f"seed {second['seed']} " in page.get_by_test_id("rehearsal-speed").inner_text()

    # opening another mission removes them (Close does too: the phone test)
    with server.client() as c:
        other = c.post("/api/missions", json=coverage_body(["rh1"])).json()["id"]
    page.get_by_test_id(f"mission-open-{other}").click()
    page.wait_for_function("(id) => window.fleetDebug.rehearsal().mission === id", arg=other)
    assert tracks_on_map(page) == 0 and page.get_by_test_id("rehearsal").is_hidden()
    with server.client() as c:
        assert c.post(f"/api/missions/{other}/abort").status_code == 200
    page.get_by_test_id(f"mission-open-{mid}").click()
    page.wait_for_function("(id) => window.fleetDebug.rehearsal().mission === id", arg=mid)
    wait_block(page, "kept")  # its latest rehearsal's figures, without tracks
    assert tracks_on_map(page) == 0
    assert axe_violations(page) == []

    # the real run (started, aborted a little later): the report sets the prediction beside the outcome
    page.get_by_test_id("mission-start").click()
    page.wait_for_function("() => document.querySelector('[data-testid=mission-status]').dataset.state === 'running'")
    assert rehearse.is_disabled()  # a running mission is not rehearsed
    page.wait_for_timeout(2000)
    # the report is what the page read once the mission ended (its separation from the telemetry stored by then:
    # a later read may have more of it, so every read of the page is kept)
    reads: list[dict[str, Any]] = []

    def on_response(r: Any) -> None:
        if r.url.endswith(f"/api/missions/{mid}") and r.request.method == "GET" and r.ok:
            reads.append(r.json())

    page.on("response", on_response)
    # The abort's own answer is held until the read its push set off has come: the order a loaded machine gave
    # once, when that answer (it carries no report figures) then took away the separation the read had brought.
    held: list[tuple[Any, Any]] = []
    abort_url = f"**/api/missions/{mid}/abort"
    page.route(abort_url, lambda route: held.append((route, route.fetch())))  # the server aborts; the page waits
    with page.expect_response(lambda r: r.url.endswith(f"/api/missions/{mid}") and r.request.method == "GET") as ended:
        page.get_by_test_id("mission-abort").click()
    m = ended.value.json()
    assert m["state"] == "aborted", m["state"]
    for _ in range(100):  # the route's handler may still be fetching the answer: let Playwright run it
        if held:
            break
        page.wait_for_timeout(50)
    assert len(held) == 1 and held[0][1].ok, held
    with page.expect_response(lambda r: r.url.endswith(f"/api/missions/{mid}/abort")):
        held[0][0].fulfill(response=held[0][1])
    page.unroute(abort_url)
    vs = page.get_by_test_id("rehearsal-vs-outcome")
    vs.wait_for()
    kept = m["rehearsal"]["predicted"]

    def row(key: str, side: str) -> str:
        return str(vs.locator(f"tr[data-figure={key}] td[data-side={side}]").inner_text())

    assert row("duration_s", "predicted") == f"{js_round(kept['duration_s'])} s"
    assert row("duration_s", "outcome").startswith(f"{js_round(m['elapsed_s'])} s")
    assert row("covered_fraction", "predicted") == f"{js_fixed(kept['covered_fraction'] * 100, 1)}%"
    assert row("covered_fraction", "outcome").startswith(f"{js_fixed(m['covered_fraction'] * 100, 1)}%")
    assert row("min_separation_m", "predicted") == f"{js_fixed(kept['min_separation_m'], 3)} m"

    def closest_shown(read: dict[str, Any]) -> str:
        closest = (read.get("separation") or {}).get("closest")
        return js_fixed(closest["distance_m"], 3) + " m" if closest else "—"

    # a push of the end may draw the report before the page's read of it (pushes carry no separation): the page
    # settles on what it read
    def agrees() -> bool:
        shown = row("min_separation_m", "outcome")
        return any(shown.startswith(closest_shown(read)) for read in reads if read["state"] == "aborted")

    for _ in range(50):
        if agrees():
            break
        page.wait_for_timeout(100)
    for _ in range(10):  # and it stays so: the abort's answer, come after the read, leaves it
        assert agrees(), (row("min_separation_m", "outcome"), reads)
        page.wait_for_timeout(100)
    assert page.get_by_test_id("rehearsal").is_hidden()  # the report has it now
    assert axe_violations(page) == []
    # the browser logs the refused request itself (the 429 above), and nothing else went wrong
    assert [e for e in rec.console_errors if "status of 429" not in e] == [], rec.console_errors


#: the mission's buttons, measured in the page (scrolling aside)
CONTROLS = {
    "plan": "[data-testid=mission-plan]",
    "rehearse": "[data-testid=mission-rehearse]",
    "start": "[data-testid=mission-start]",
    "abort": "[data-testid=mission-abort]",
}


def page_boxes(page: Any, controls: dict[str, str]) -> dict[str, list[float]]:
    scroll = page.evaluate("() => scrollY")
    return {k: [b[0], b[1] + scroll, b[2], b[3]] for k, b in boxes(page, controls).items()}


def test_rehearse_on_a_phone_moves_no_button(
    server: ServerProcess,
    spawn_agent: Callable[..., AgentProcess],
    mqtt_probe: Callable[..., MqttProbe],
    page_factory: Callable[..., tuple[Any, Any]],
) -> None:
    """390x844 with touch: Rehearse is as big as the buttons beside it; while the twin runs (the request held
    here until measured) and when the figures come, no button moved; the figures come under the buttons; a tap
    on Close removes them and the tracks."""
    start_fleet(spawn_agent, mqtt_probe, server)
    with server.client() as c:
        mid = c.post("/api/missions", json=coverage_body(list(ROBOTS))).json()["id"]
    page, rec = open_page(page_factory, f"/missions/{mid}", "phone")
    page.wait_for_function("() => document.querySelector('[data-testid=mission-status]').dataset.state === 'draft'")
    rehearse = page.get_by_test_id("mission-rehearse")
    rehearse.scroll_into_view_if_needed()
    wait_boxes_settled(page, list(CONTROLS.values()))
    before = page_boxes(page, CONTROLS)
    assert before["rehearse"][3] == before["start"][3] == before["plan"][3], before  # as tall as the others
    assert before["rehearse"][3] >= 30 and before["rehearse"][2] >= 44, before

    held: list[Any] = []
    page.route("**/rehearsal", lambda route: held.append(route))
    rehearse.tap()
    wait_held(page, held, 1, "rehearsals")
    rehearse.tap(force=True)  # a second tap on the busy button sends nothing
    wait_frames(page)
    assert rehearse.is_disabled() and rehearse.get_attribute("aria-busy") == "true"
    assert page_boxes(page, CONTROLS) == before, "turning busy moved a button"
    busy_close = page_boxes(page, {"close": "[data-testid=rehearsal-close]"})["close"]
    assert busy_close[3] == before["start"][3]
    held[0].continue_()
    wait_block(page, "drawn")
    wait_frames(page)
    assert len(held) == 1, "the busy button sent a second rehearsal"
    assert page_boxes(page, CONTROLS) == before, "the figures moved a button"
    assert page_boxes(page, {"close": "[data-testid=rehearsal-close]"})["close"] == busy_close
    block = page_boxes(page, {"block": "[data-testid=rehearsal]"})["block"]
    assert block[1] >= max(b[1] + b[3] for b in before.values()), "the figures are not under the buttons"
    assert tracks_on_map(page) == 3
    assert page.evaluate("() => document.documentElement.scrollWidth <= innerWidth")
    assert axe_violations(page) == []
    # Close removes the tracks and the figures
    page.get_by_test_id("rehearsal-close").tap()
    page.wait_for_function("() => document.querySelector('[data-testid=rehearsal]').dataset.state === 'none'")
    assert tracks_on_map(page) == 0 and page.get_by_test_id("rehearsal").is_hidden()
    assert page_boxes(page, CONTROLS) == before
    assert not rec.console_errors, rec.console_errors
