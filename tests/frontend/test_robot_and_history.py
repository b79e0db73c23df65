"""Robot page (camera + AprilTag overlay, live charts), history with export, and recovery after a server
restart: real Chromium, real server and broker, simulated robots with a rendered camera."""

from __future__ import annotations

import csv
import io
import math
import time
from urllib.parse import parse_qs, urlsplit

import pytest
from playwright.sync_api import TimeoutError as PlaywrightTimeoutError
from playwright.sync_api import expect

from tests.backend.helpers import driveable, wait_robot
from tests.frontend.conftest import SCREENSHOTS
from tests.frontend.console_support import wait_frames
from tests.support.procs import wait_for


@pytest.mark.slow
def test_robot_page_shows_camera_frames_with_the_tag_overlay(server, spawn_agent, page_factory):
    spawn_agent("cam-1", "--camera", "--start-pose=1,0,0")  # faces tag 0 on the east wall, 1 m away
    with server.client() as c:
        wait_robot(c, "cam-1", lambda r: "camera" in r["capabilities"]["sensors"] and r["position"], timeout=30)
    page, rec = page_factory()
    page.goto("/robots/cam-1")  # deep link
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.camera().frames >= 5", timeout=20000)
    page.wait_for_function("() => window.fleetDebug.camera().overlays >= 3", timeout=10000)
    # the info line shows the rate as soon as frames flow (a loaded machine may have paused them before)
    expect(page.get_by_test_id("camera-info")).to_contain_text("fps", timeout=5000)
    # the overlay canvas really has the tag outline drawn where the tag is in the image (each new frame
    # clears it until its detections arrive, so wait for a drawn one rather than read one instant)
    count = """() => {
      const c = document.querySelector('[data-testid=overlay-canvas]');
      const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
      let cyan = 0, any = 0;
      for (let i = 0; i < d.length; i += 4) {
        if (d[i + 3] > 0) any++;
        if (d[i] < 60 && d[i + 1] > 180 && d[i + 2] > 200 && d[i + 3] > 200) cyan++;
      }
      return {cyan, any, w: c.width, h: c.height};
    }"""
    # what the wait saw when it held is what is checked: a read after it may fall on a frame just cleared (a
    # clean-clone run read an empty overlay right after the wait had seen the outline)
    try:
        held = page.wait_for_function(
            f"() => {{ const r = ({count})(); return r.cyan > 100 ? r : null; }}", timeout=10000
        )
    except PlaywrightTimeoutError as exc:
        raise AssertionError(f"no outline drawn in 10 s; the overlay now: {page.evaluate(count)}") from exc
    drawn = held.json_value()
    assert (drawn["w"], drawn["h"]) == (640, 480)
    assert drawn["cyan"] > 100, drawn  # the outline (a ~50 px square at 1 m) in the overlay colour
    # the camera canvas shows a real image (not black)
    bright = page.evaluate("""() => {
      const c = document.querySelector('[data-testid=camera-canvas]');
      const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
      let s = 0; for (let i = 0; i < d.length; i += 400) s += d[i]; return s / (d.length / 400);
    }""")
    assert bright > 40
    # toggling the overlay off clears it
    page.get_by_test_id("overlay-toggle").uncheck()
    page.wait_for_function(
        """() => {
      const c = document.querySelector('[data-testid=overlay-canvas]');
      const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
      let n = 0; for (let i = 3; i < d.length; i += 4) if (d[i]) n++; return n === 0;
    }""",
        timeout=5000,
    )  # cleared
    page.get_by_test_id("overlay-toggle").check()
    # live charts are drawn
    page.wait_for_function("() => document.getElementById('chart-xyz').data?.[0]?.x.length > 5", timeout=10000)
    page.wait_for_function(
        "() => document.getElementById('chart-tags').data?.[0]?.y.some((n) => n >= 1)", timeout=10000
    )
    wait_frames(page)  # the charts' redraw of what arrived is on screen for the picture
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SCREENSHOTS / "robot.png"))
    # back to the fleet with the browser's back button... after navigating there by link
    page.get_by_role("link", name="← Fleet").click()
    page.wait_for_url("**/")
    page.go_back()
    page.wait_for_url("**/robots/cam-1")
    assert page.get_by_test_id("robot-title").inner_text() == "cam-1"
    assert rec.console_errors == [], rec.console_errors


def test_the_tag_outline_stays_while_the_detector_lags_a_frame_behind(server, page_factory):
    """On a loaded robot the detections of frame N came after frame N+1 was shown: each new frame cleared the
    outline before its own detections came, and the view showed none at all. The outline of a frame at most
    three older is kept; one further behind, or none, is cleared."""
    page, rec = page_factory()
    page.goto("/")
    result = page.evaluate("""async () => {
      const { CameraView } = await import("/assets/js/robot/camera.js");
      const make = (tag) => Object.assign(document.createElement(tag), { width: 64, height: 48 });
      const toggle = Object.assign(document.createElement("input"), { type: "checkbox", checked: true });
      const feed = { start() {}, stop() {} };
      const view = new CameraView({ canvas: make("canvas"), overlay: make("canvas"), info: make("div"), toggle, feed });
      const jpeg = await new Promise((ok) => make("canvas").toBlob(ok, "image/jpeg"));
      const bytes = await jpeg.arrayBuffer();
      const detection = { tag_id: 7, corners: [[10, 10], [30, 10], [30, 30], [10, 30]], center: [20, 20] };
      const tag = (seq) => ({ frame_seq: seq, image_size: [64, 48], detections: [detection] });
      const drawn = () => view.overlay.dataset.frameSeq ?? null;
      const seen = [];
      for (let seq = 1; seq <= 4; seq++) {  // each frame's detections come after the next frame
        await view.showFrame(bytes, { frame_seq: seq, ts: seq });
        if (seq > 1) view.noteDetections(tag(seq - 1));
        seen.push(drawn());
      }
      await view.showFrame(bytes, { frame_seq: 9, ts: 9 });  // five frames on, nothing of them: cleared
      seen.push(drawn());
      return seen;
    }""")
    assert result == [None, "1", "2", "3", None]
    assert rec.console_errors == [], rec.console_errors


def test_history_chart_and_csv_export_hold_the_stored_points(server, spawn_agent, page_factory, tmp_path):
    spawn_agent("hist-1", "--start-pose=0,0,0")
    with server.client() as c:
        wait_robot(c, "hist-1", driveable, timeout=30)
        drive = {"command": "move_forward", "args": {"speed": 1, "duration_s": 1}}
        c.post("/api/robots/hist-1/commands?wait=3", json=drive)

        def drive_stored() -> bool:
            params = {"stream": "position", "start": time.time() - 60, "max_points": 10000}
            xs = [p["data"]["x"] for p in c.get("/api/robots/hist-1/telemetry", params=params).json()["points"]]
            return bool(xs) and max(xs) - min(xs) > 0.2

        wait_for(drive_stored, 10, what="the drive in the stored telemetry")
        end = math.ceil(time.time())  # the page's time inputs have whole seconds
        start = end - 60
        stored = c.get(
            "/api/robots/hist-1/telemetry",
            params={"stream": "position", "start": start, "end": end, "max_points": 10000},
        ).json()
    assert not stored["downsampled"]
    page, _ = page_factory()
    page.goto(f"/history?robots=hist-1&stream=position&start={start:.0f}&end={end:.0f}&field=x")
    page.wait_for_function("() => document.getElementById('history-chart').data?.[0]?.x.length > 10", timeout=15000)
    assert "position.x" in page.get_by_test_id("history-info").inner_text()
    # the chart breaks its line with a null wherever the stored series has a gap (a robot starved of CPU on a
    # loaded machine pauses its stream): the points are the numbers
    xs = page.evaluate("() => document.getElementById('history-chart').data[0].y.filter((v) => v !== null)")
    assert max(xs) - min(xs) > 0.2  # the drive shows in the chart
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SCREENSHOTS / "history.png"))
    with page.expect_download() as dl:
        page.get_by_test_id("export-csv").click()
    path = tmp_path / "export.csv"
    dl.value.save_as(path)
    rows = list(csv.DictReader(line for line in io.StringIO(path.read_text()) if not line.startswith("#")))
    # the export is the stored points of the same range: every one, exact values
    by_seq = {p["seq"]: p for p in stored["points"]}
    exported = [r for r in rows if int(r["seq"]) in by_seq]
    assert len(exported) >= len(stored["points"])
    for r in exported[:200]:
        p = by_seq[int(r["seq"])]
        assert float(r["x"]) == p["data"]["x"] and float(r["ts"]) == p["ts"]
    with page.expect_download() as dl:
        page.get_by_test_id("export-json").click()
    assert dl.value.suggested_filename.endswith(".json")

    # zooming refetches just the zoomed range from the server
    n = len(stored["points"])
    # from just before one stored point to just after another (the browser's dates have whole ms)
    lo, hi = stored["points"][n // 4]["ts"] - 0.005, stored["points"][3 * n // 4]["ts"] + 0.005
    inside = [p for p in stored["points"] if lo <= p["ts"] <= hi]

    def zoom_fetch(request) -> bool:
        url = urlsplit(request.url)
        q = parse_qs(url.query)
        return (
            url.path == "/api/robots/hist-1/telemetry"
            and abs(float(q["start"][0]) - lo) < 0.01
            and abs(float(q["end"][0]) - hi) < 0.01
        )

    with page.expect_request(zoom_fetch):
        page.evaluate(
            "([a, b]) => Plotly.relayout('history-chart', {'xaxis.range': [new Date(a), new Date(b)]})",
            [lo * 1000, hi * 1000],
        )
    page.get_by_test_id("history-info").filter(has_text="in the zoomed range").wait_for()
    shown = page.evaluate("() => document.getElementById('history-chart').data[0].x.map((d) => d.getTime() / 1000)")
    assert shown and lo - 0.002 <= min(shown) and max(shown) <= hi + 0.002, (lo, hi, shown[:3], shown[-3:])
    assert len(shown) >= len(inside) > 2  # every stored point of the zoomed range (not downsampled)
    page.evaluate("() => Plotly.relayout('history-chart', {'xaxis.autorange': true})")  # double click: back out
    page.wait_for_function(
        "(n) => document.getElementById('history-chart').data[0].x.length >= n", arg=len(stored["points"])
    )

    # the query lives in the URL: a new range is a new history entry, and back restores the old one
    first_url = page.url
    page.get_by_role("button", name="5 min").click()
    page.wait_for_url(lambda u: u != first_url and "robots=hist-1" in u and "stream=position" in u)
    page.go_back()
    page.wait_for_url(first_url)
    page.wait_for_function(
        "(t) => new Date(document.getElementById('h-start').value).getTime() / 1000 === t", arg=start
    )
    page.get_by_test_id("history-info").filter(has_text="position.x").wait_for()


def test_page_recovers_after_a_server_restart_without_reload(server, spawn_agent, page_factory):
    spawn_agent("rs-1", "--start-pose=0,0,0")
    with server.client() as c:
        wait_robot(c, "rs-1", lambda r: r["online"] and r["position"], timeout=30)
    page, _ = page_factory()
    page.goto("/")
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    page.evaluate("() => { window.__marker = 42; }")  # proves there was no reload
    server.stop()
    page.get_by_test_id("ws-banner").wait_for(state="visible", timeout=10000)
    server.start()
    page.get_by_test_id("ws-banner").wait_for(state="hidden", timeout=20000)
    page.wait_for_function("() => window.fleetDebug.wsConnected()")
    assert page.evaluate("() => window.__marker") == 42
    # live data flows again: the robot's plotted position updates after the restart
    t0 = time.time()
    page.wait_for_function(f"() => (window.fleetDebug.robots()['rs-1']?.position?.ts ?? 0) > {t0}", timeout=15000)
    assert page.get_by_test_id("robot-row-rs-1").get_attribute("data-online") == "true"
