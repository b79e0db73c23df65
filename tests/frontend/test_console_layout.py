"""The console's layout and e-stop details at 1280x720 (issue 21, items 2, 6, 11 and 12), in a real
Chromium against a real server, broker and simulated robots."""

from __future__ import annotations

import pytest

from tests.backend.helpers import wait_robot
from tests.frontend.conftest import FLEET
from tests.frontend.console_support import (
    DEVICES,
    TOUCH,
    boxes,
    inside_viewport,
    no_horizontal_overflow,
    open_page,
    wait_frames,
    wait_list_render,
)

PANELS = {sel: sel for sel in ("#fleet-map", ".list-panel", ".side-panel", "main")}
MAP_AXES = """() => { const f = document.getElementById('fleet-map')._fullLayout;
  return [f.xaxis._length, f.yaxis._length, f.width, f.height]; }"""


def test_robot_table_is_not_clipped_at_1280x720_with_cameras(server, fleet, spawn_agent, page_factory):
    for rid, pose in (("camera-robot-1", "0,0,0"), ("camera-robot-2", "0.5,0,0")):
        spawn_agent(rid, "--camera", f"--start-pose={pose}")
    with server.client() as c:
        for rid in ("camera-robot-1", "camera-robot-2"):
            wait_robot(c, rid, lambda r: "camera" in r["capabilities"]["sensors"] and r["online"], timeout=30)
    page, _ = open_page(page_factory, "/")
    page.locator("[data-testid=robot-row-camera-robot-1] .sensors", has_text="camera").wait_for()
    no_horizontal_overflow(page)
    panel = page.evaluate("""() => { const p = document.querySelector('.list-panel'), t = p.querySelector('table');
      const pr = p.getBoundingClientRect(), tr = t.getBoundingClientRect();
      return {scroll: p.scrollWidth, client: p.clientWidth, tableRight: tr.right, panelRight: pr.right}; }""")
    assert panel["scroll"] <= panel["client"] and panel["tableRight"] <= panel["panelRight"], panel
    # every Rate cell is fully inside the panel and the viewport (all measured in one script task: the list
    # re-renders every second, and a cell it replaced between two reads has no box)
    rights = page.evaluate(
        "() => Array.from(document.querySelectorAll('#robot-rows tr td:nth-child(4)'),"
        " (td) => td.getBoundingClientRect().right)"
    )
    assert len(rights) == len(FLEET) + 2
    for right in rights:
        assert right <= panel["panelRight"] and right <= 1280, (right, panel)
    inside_viewport(page, ".list-panel th[data-sort=rate]")


@pytest.mark.parametrize("device", [None, "tablet", "phone"])
def test_estop_bar_names_who_pressed_it_and_moves_nothing(server, fleet, page_factory, device):
    page, _ = open_page(page_factory, "/", device)
    page.get_by_test_id("robot-row-snail-1").wait_for()
    page.wait_for_function("() => document.getElementById('fleet-map')._fullLayout?.xaxis?._length > 0")
    before, axes_before = boxes(page, PANELS), page.evaluate(MAP_AXES)
    ready = page.evaluate(
        "() => { const s = getComputedStyle(document.querySelector('[data-testid=estop]'));"
        " return [s.backgroundImage, s.backgroundColor, s.boxShadow]; }"
    )
    with server.client() as c:  # pressed by someone else: the bar says who, from the server's state
        assert c.post("/api/estop", json={"reason": "diver in the pool", "source": "pytest"}).status_code == 202
        assert c.get("/api/estop").json()["source"] == "FLEET_ADMIN_TOKEN via pytest"
    page.get_by_test_id("estop-bar").wait_for()
    reason = page.get_by_test_id("estop-reason").inner_text()
    assert "pressed by FLEET_ADMIN_TOKEN via pytest" in reason and "diver in the pool" in reason, reason
    # the latched E-STOP looks different from the ready one and says so
    estop = page.get_by_test_id("estop")
    assert estop.inner_text() == "E-STOPPED" and estop.get_attribute("aria-pressed") == "true"
    latched = page.evaluate(
        "() => { const s = getComputedStyle(document.querySelector('[data-testid=estop]'));"
        " return [s.backgroundImage, s.backgroundColor, s.boxShadow]; }"
    )
    assert latched != ready and "gradient" in latched[0], (ready, latched)
    # nothing under the bar moved or resized; the map kept its scale
    page.locator("[data-testid=estop-acks] li.acked").first.wait_for()
    wait_frames(page)  # a resize would have been observed and redrawn by now (ResizeObserver + rAF)
    assert boxes(page, PANELS) == before
    assert page.evaluate(MAP_AXES) == axes_before
    # pressed from this page: the bar names this user
    with server.client() as c:
        c.post("/api/estop/release", json={"source": "test"})
    page.get_by_test_id("estop-bar").wait_for(state="hidden")
    assert boxes(page, PANELS) == before
    page.get_by_test_id("estop").click()  # (a tap on touch devices: the click Playwright sends is one)
    page.get_by_test_id("estop-reason").filter(has_text="pressed by browser-admin via ui").wait_for()
    with server.client() as c:
        assert c.get("/api/estop").json()["source"] == "browser-admin via ui"
        c.post("/api/estop/release", json={"source": "test"})


@pytest.mark.parametrize("device", [None, "phone", "tablet"])
def test_robot_without_camera_gets_no_black_box_and_imu_labels_fit(server, fleet, spawn_agent, page_factory, device):
    spawn_agent("cam-1", "--camera", "--start-pose=1,0,0")
    with server.client() as c:
        wait_robot(c, "cam-1", lambda r: "camera" in r["capabilities"]["sensors"] and r["online"], timeout=30)
    page, _ = open_page(page_factory, "/robots/snail-1", device)
    page.get_by_test_id("no-camera").wait_for()
    assert page.get_by_test_id("camera-box").is_hidden()
    assert page.get_by_test_id("camera-info").is_hidden()
    # the IMU chart's right axis (rad/s) labels lie inside the chart
    page.wait_for_function("() => document.querySelectorAll('#chart-imu .y2tick text').length >= 2")
    fit = page.evaluate("""() => { const c = document.getElementById('chart-imu').getBoundingClientRect();
      return [...document.querySelectorAll('#chart-imu .y2tick text, #chart-imu .g-y2title text')].map((t) => {
        const r = t.getBoundingClientRect(); return [t.textContent, r.left >= c.left, r.right <= c.right]; }); }""")
    assert fit and all(inside for _, *sides in fit for inside in sides), fit
    # a robot with a camera still gets its camera box
    page.goto("/robots/cam-1")
    page.wait_for_function("() => window.fleetDebug?.camera().frames >= 1", timeout=20000)
    assert page.get_by_test_id("camera-box").is_visible() and page.get_by_test_id("no-camera").is_hidden()


@pytest.mark.parametrize("device", [None, "phone", "tablet"])
def test_online_robots_first_and_hide_offline_is_remembered(server, fleet, spawn_agent, page_factory, device):
    gone = spawn_agent("aaa-gone", "--start-pose=0,0,0")  # sorts first by name
    page, _ = open_page(page_factory, "/", device)
    press = (lambda loc: loc.tap()) if device else (lambda loc: loc.click())
    page.locator("[data-testid=robot-row-aaa-gone][data-online=true]").wait_for()
    order = "() => [...document.querySelectorAll('#robot-rows tr')].map((r) => r.dataset.robotId)"
    assert page.evaluate(order)[0] == "aaa-gone"
    gone.stop()
    page.locator("[data-testid=robot-row-aaa-gone][data-online=false]").wait_for(timeout=20000)
    assert page.evaluate(order) == [*sorted(FLEET), "aaa-gone"]  # online first, then by name
    press(page.locator("th[data-sort=id] button"))  # by name, descending: still online first
    page.wait_for_function(f"() => ({order})().join() === '{','.join([*sorted(FLEET, reverse=True), 'aaa-gone'])}'")
    press(page.get_by_test_id("hide-offline"))
    page.wait_for_function(f"() => ({order})().length === {len(FLEET)}")
    assert "1 offline hidden" in page.locator("#robot-count").text_content()
    page.reload()  # remembered
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    page.get_by_test_id("robot-row-snail-1").wait_for()
    assert page.get_by_test_id("hide-offline").is_checked()
    wait_list_render(page)  # the list re-rendered since the reload: the gone robot would be back by now
    assert "aaa-gone" not in page.evaluate(order)
    press(page.get_by_test_id("hide-offline"))
    page.get_by_test_id("robot-row-aaa-gone").wait_for()


@pytest.mark.parametrize("device", [None, "phone"])
def test_api_docs_render_and_try_it_out_runs(server, spawn_agent, page_factory, device):
    spawn_agent("doc-1", "--start-pose=0,0,0")
    with server.client() as c:
        wait_robot(c, "doc-1", lambda r: r["online"], timeout=30)
    page, rec = page_factory(**DEVICES[device], **TOUCH) if device else page_factory()
    page.goto("/docs")
    page.locator(".swagger-ui .info .title", has_text="Mollusca Fleet").wait_for(timeout=20000)
    assert "Unable to render" not in page.content()
    # Swagger UI 5 (4.x cannot render OpenAPI 3.1, which the server publishes)
    served = page.evaluate(
        "async () => (await (await fetch('/static/swagger/swagger-ui-bundle.js')).text())"
        '.match(/PACKAGE_VERSION:"([^"]+)"/)[1]'
    )
    assert served.startswith("5."), served
    assert page.evaluate("async () => (await (await fetch('/openapi.json')).json()).openapi").startswith("3.1")
    ops = page.locator(".opblock-summary-path")
    ops.first.wait_for()
    paths = set(ops.all_inner_texts())
    assert {"/api/robots", "/api/estop", "/api/users"} <= {p.replace("\u200b", "") for p in paths}, paths
    op = page.locator("#operations-robots-list_robots_api_robots_get")
    press = (lambda loc: loc.tap()) if device else (lambda loc: loc.click())
    press(op.locator(".opblock-summary"))
    press(op.get_by_role("button", name="Try it out"))
    press(op.get_by_role("button", name="Execute"))
    status = op.locator(".live-responses-table tbody .response-col_status").first
    status.wait_for(timeout=10000)
    assert status.inner_text().strip() == "200"
    body = op.locator(".live-responses-table tbody .response-col_description .microlight").first.inner_text()
    assert '"id": "doc-1"' in body, body  # the live fleet, through the browser's own session
    hosts = {r.split("/")[2] for r in rec.requests if r.startswith("http")}
    assert hosts <= {f"127.0.0.1:{server.port}"}, hosts  # nothing from a CDN
    assert rec.console_errors == [], rec.console_errors
