"""The runs page in a real Chromium against a real server and simulated robots: start a run, add a marker
with the M key and with the button, stop it, replay it in the live components (the map, the camera with its
AprilTag overlay, the command log and the events at the seeked time; a marker; play at 4x), find it,
export it (the file downloads with a progress bar, and it is the run), and delete it (admin, two presses)."""

from __future__ import annotations

import io
import json
import re
import time
import zipfile
from collections import defaultdict

import pytest
from mcap.reader import make_reader

from tests.frontend.console_support import axe_violations, open_page
from tests.support.procs import wait_for
from tests.support.runs import raw_rows, wait_online

#: the replay's event list holds n markers
MARKERS_LISTED = "n => document.querySelectorAll('[data-testid=replay-events] li[data-kind=marker]').length === n"


@pytest.mark.slow
def test_start_mark_stop_find_and_export_a_run(server, fleet, spawn_agent, page_factory, tmp_path):
    spawn_agent("cam-1", "--camera", "--start-pose=0,-0.5,0")  # faces the +x wall's tag
    with server.client() as c:
        wait_online(c, ["cam-1"])
        wait_for(lambda: c.get("/api/robots/cam-1/camera/latest.jpg").status_code == 200, 20)
    page, rec = open_page(page_factory, "/")
    page.get_by_test_id("nav-runs").click()
    page.wait_for_url("**/runs")
    page.get_by_test_id("run-name").fill("browser trial")
    page.get_by_test_id("run-tags").fill("ui, current-on")
    page.get_by_test_id("run-robots").select_option(["cam-1", "snail-1", "snail-2"])
    page.get_by_test_id("run-start").click()
    page.wait_for_url("**/runs/*")
    page.get_by_test_id("run-title").filter(has_text="browser trial").wait_for()
    run_id = int(page.url.rsplit("/", 1)[1])
    with server.client() as c:
        run = c.get(f"/api/runs/{run_id}").json()
    assert run["running"] and run["robots"] == ["cam-1", "snail-1", "snail-2"] and run["tags"] == ["ui", "current-on"]
    with server.client() as c:  # a command during the run: the replay's command log lists it from its time on
        sent = c.post("/api/robots/snail-1/commands", json={"command": "turn_left", "args": {"duration_s": 0.5}})
        assert sent.status_code in (200, 202), sent.text
        command = sent.json()

    # the M key marks the moment (focus outside any text field); the button with a text
    page.get_by_test_id("run-title").click()
    page.keyboard.press("m")
    page.get_by_test_id("run-markers").locator("li").first.wait_for()
    page.get_by_test_id("marker-text").fill("tag 3 fell")
    page.get_by_test_id("marker-add").click()
    page.get_by_test_id("run-markers").locator("li", has_text="tag 3 fell").wait_for()
    # typing an M into the text field is text, not a marker
    page.get_by_test_id("marker-text").press("m")
    with server.client() as c:
        markers = c.get(f"/api/runs/{run_id}/markers").json()
    assert [m["text"] for m in markers] == ["marker", "tag 3 fell"]

    page.wait_for_timeout(1500)
    page.get_by_test_id("run-stop").click()
    page.get_by_test_id("run-ended").filter(has_text=":").wait_for()
    with server.client() as c:
        run = c.get(f"/api/runs/{run_id}").json()
    assert not run["running"] and run["summary"]["messages_total"] > 0
    assert page.get_by_test_id("run-messages").inner_text() == str(run["summary"]["messages_total"])

    # replay: seek to the middle, the map (the live FleetMap) shows each robot where the stored track has it
    replay_map = page.get_by_test_id("replay-map")
    replay_map.wait_for()
    page.wait_for_function("() => document.querySelector('[data-testid=replay-map]').dataset.t")
    page.eval_on_selector(
        "[data-testid=replay-scrubber]", "e => { e.value = 500; e.dispatchEvent(new Event('input')); }"
    )
    t = float(replay_map.get_attribute("data-t"))
    assert abs(t - (run["started_at"] + run["ended_at"]) / 2) < (run["ended_at"] - run["started_at"]) / 500
    shown = json.loads(replay_map.get_attribute("data-shown"))
    with server.client() as c:
        for robot in ("cam-1", "snail-1", "snail-2"):
            rows = raw_rows(c, robot, "position", run["started_at"], t)
            assert shown[robot]["ts"] == rows[-1]["ts"]
            assert shown[robot]["x"] == pytest.approx(rows[-1]["data"]["x"])
    assert "snail-3" not in shown
    # ... drawn by the map itself, at the pixels of its projection (the site the run recorded around them)
    page.wait_for_function(
        "() => Object.keys(window.fleetDebug.replayMapRobots()).length === 3"
        " && window.fleetDebug.replayMapRobots()['snail-1'].x === JSON.parse("
        "document.querySelector('[data-testid=replay-map]').dataset.shown)['snail-1'].x"
    )

    # the camera at a moment: the stored frame at or before it, with the AprilTag overlay of that very frame
    with server.client() as c:
        sightings = [
            r for r in raw_rows(c, "cam-1", "apriltag", run["started_at"], run["ended_at"]) if r["data"]["detections"]
        ]
        assert sightings, "the simulated camera saw no tag"
        frame = None
        for r in sightings:  # one whose frame was kept (the run keeps 5 of the camera's 10 fps)
            got = c.get(f"/api/runs/{run_id}/frames", params={"robot": "cam-1", "at": repr(r["ts"])})
            if got.status_code == 404:  # a sighting before the run's first kept frame: none at or before it
                assert got.json()["code"] == "no_frame", got.text
                continue
            answer = got.json()
            if answer["frame_seq"] == r["data"]["frame_seq"]:
                frame = answer
                break
        assert frame is not None
    page.get_by_test_id("replay-camera-robot").select_option("cam-1")
    page.evaluate("t => window.fleetDebug.replaySeek(t)", frame["ts"] + 0.01)
    canvas, overlay = page.get_by_test_id("replay-camera-canvas"), page.get_by_test_id("replay-overlay-canvas")
    assert canvas.get_attribute("data-frame-seq") == str(frame["frame_seq"])
    assert overlay.get_attribute("data-frame-seq") == str(frame["frame_seq"])
    tag_ids = [str(d["tag_id"]) for d in frame["detections"]["detections"]]
    assert overlay.get_attribute("data-tags") == ",".join(tag_ids)
    assert "tag" in page.get_by_test_id("replay-camera-info").inner_text()
    # the overlay toggle clears it, as live
    page.get_by_test_id("replay-overlay-toggle").uncheck()
    assert overlay.get_attribute("data-tags") == ""
    page.get_by_test_id("replay-overlay-toggle").check()
    assert overlay.get_attribute("data-tags") == ",".join(tag_ids)

    # the command log and the events follow the replay time: before the command and the markers, none of
    # them; after, each is listed (the command with its acks received by then)
    log, events = page.get_by_test_id("replay-command-log"), page.get_by_test_id("replay-events")
    page.evaluate("t => window.fleetDebug.replaySeek(t)", min(command["ts"], markers[0]["ts"]) - 0.05)
    page.wait_for_function("() => document.querySelector('[data-testid=replay-command-log] li.empty')")
    assert log.locator(f"li[data-id='{command['id']}']").count() == 0
    assert events.locator("li[data-kind=marker]").count() == 0
    assert events.locator("li[data-kind=run_start]").count() == 1
    page.evaluate("t => window.fleetDebug.replaySeek(t)", markers[1]["ts"] + 0.01)
    log.locator(f"li[data-id='{command['id']}']").wait_for()
    assert log.locator(f"li[data-id='{command['id']}']").get_attribute("data-command") == "turn_left"
    assert events.locator("li[data-kind=marker]", has_text="tag 3 fell").count() == 1
    assert events.locator("li[data-kind=marker]").count() == 2

    # a marker on the timeline seeks to it; play at 4x runs to the end and stops there, the views along
    page.get_by_test_id("replay-marker").filter(has_text="marker").first.click()
    assert float(replay_map.get_attribute("data-t")) == pytest.approx(markers[0]["ts"])
    page.wait_for_function(MARKERS_LISTED, arg=1)
    page.get_by_test_id("replay-speed").select_option("4")
    page.get_by_test_id("replay-play").click()
    page.get_by_test_id("replay-play").filter(has_text="Play").wait_for(timeout=10_000)
    assert float(replay_map.get_attribute("data-t")) == pytest.approx(run["ended_at"])
    page.wait_for_function(MARKERS_LISTED, arg=2)
    with server.client() as c:  # the camera ends on the run's last stored frame
        last = c.get(f"/api/runs/{run_id}/frames", params={"robot": "cam-1", "at": repr(run["ended_at"])}).json()
    wait_for(lambda: canvas.get_attribute("data-frame-seq") == str(last["frame_seq"]), 10)

    # export this range: the selection from the first marker to the end, from the scrubber
    page.get_by_test_id("replay-marker").filter(has_text="marker").first.click()
    page.get_by_test_id("replay-range-from").click()
    page.eval_on_selector(
        "[data-testid=replay-scrubber]", "e => { e.value = 1000; e.dispatchEvent(new Event('input')); }"
    )
    page.get_by_test_id("replay-range-to").click()
    lo = float(page.get_by_test_id("replay-range").get_attribute("data-from"))
    hi = float(page.get_by_test_id("replay-range").get_attribute("data-to"))
    assert lo == pytest.approx(markers[0]["ts"]) and hi == pytest.approx(run["ended_at"]) and lo > run["started_at"]
    with page.expect_download() as dl:
        page.get_by_test_id("replay-export-range").click()
    assert re.fullmatch(rf"run-{run_id}-[0-9.]+s-[0-9.]+s\.mcap", dl.value.suggested_filename), (
        dl.value.suggested_filename
    )
    rpath = tmp_path / "range.mcap"
    dl.value.save_as(rpath)
    in_range = defaultdict(int)
    for _, channel, message in make_reader(io.BytesIO(rpath.read_bytes())).iter_messages():
        # the range is of the stamps (a robot's own, its message's publish time; its log time is moved onto
        # the server's clock by its measured offset)
        assert round(lo * 1e9) <= message.publish_time <= round(hi * 1e9), channel.topic
        in_range[channel.topic] += 1
    with server.client() as c:
        assert in_range["/snail-1/position"] == len(raw_rows(c, "snail-1", "position", lo, hi)) > 0
    assert in_range["/markers"] == 2  # both markers lie within [first marker, end]

    # search: by tag finds it, by another robot does not
    page.get_by_test_id("runs-search-tag").fill("current-on")
    page.get_by_test_id("runs-search").click()
    page.locator("[data-testid=run-rows] tr[data-run-id]").first.wait_for()
    assert page.locator("[data-testid=run-rows] tr[data-run-id]").count() == 1
    page.get_by_test_id("runs-search-tag").fill("")
    page.get_by_test_id("runs-search-robot").fill("snail-3")
    page.get_by_test_id("runs-search").click()
    page.get_by_test_id("run-rows").filter(has_text="No runs found").wait_for()

    # export: the MCAP downloads, the progress bar fills, and the file is the run
    with page.expect_download() as dl:
        page.get_by_test_id("export-mcap").click()
    path = tmp_path / "run.mcap"
    dl.value.save_as(path)
    assert dl.value.suggested_filename == f"run-{run_id}.mcap"
    wait_for(lambda: page.get_by_test_id("export-progress").get_attribute("value") == "1", 5)
    reader = make_reader(io.BytesIO(path.read_bytes()))
    positions = sum(1 for _ in reader.iter_messages(topics=["/snail-1/position"]))
    counts = {(m["robot_id"], m["stream"]): m["count"] for m in run["summary"]["messages"]}
    assert positions == counts[("snail-1", "position")]
    with page.expect_download() as dl:
        page.get_by_test_id("export-zip").click()
    zpath = tmp_path / "run.zip"
    dl.value.save_as(zpath)
    with zipfile.ZipFile(zpath) as zf:
        assert "run.json" in zf.namelist()

    assert axe_violations(page) == []
    assert not rec.console_errors, rec.console_errors

    # the markers show on the history plot (dashed lines with their text) and in the event list
    start, end = int(run["started_at"]) - 1, int(run["ended_at"]) + 2
    page.goto(f"/history?robots=snail-1&stream=position&start={start}&end={end}&fields=x&mode=time")
    page.wait_for_function(
        "() => (document.querySelector('[data-testid=history-chart]').layout?.shapes ?? []).length === 2"
    )
    texts = page.evaluate(
        "() => document.querySelector('[data-testid=history-chart]').layout.annotations.map(a => a.text)"
    )
    assert sorted(texts) == ["marker", "tag 3 fell"]
    page.goto("/")
    page.locator("[data-testid=events] li[data-kind=marker]", has_text="tag 3 fell").wait_for()
    # compare with a second run on the same map: its trails dashed, at the same time since its start
    with server.client() as c:
        other = c.post("/api/runs", json={"name": "second trial", "robots": ["snail-1"]}).json()
        c.post("/api/robots/snail-1/commands", json={"command": "turn_left", "args": {"duration_s": 1.0}})
        wait_for(lambda: len(raw_rows(c, "snail-1", "position", other["started_at"], time.time())) > 10, 20)
        other = c.post(f"/api/runs/{other['id']}/stop").json()
    page.goto(f"/runs/{run_id}")
    page.get_by_test_id("run-title").filter(has_text="browser trial").wait_for()
    page.wait_for_function("() => document.querySelector('[data-testid=replay-map]').dataset.t")
    page.get_by_test_id("replay-compare").select_option(str(other["id"]))
    page.wait_for_function("() => document.querySelector('[data-testid=replay-map]').dataset.compare")
    page.eval_on_selector(
        "[data-testid=replay-scrubber]", "e => { e.value = 400; e.dispatchEvent(new Event('input')); }"
    )
    t = float(page.get_by_test_id("replay-map").get_attribute("data-t"))
    compare = json.loads(page.get_by_test_id("replay-map").get_attribute("data-compare"))
    assert compare["run"] == other["id"]
    assert compare["t"] == pytest.approx(other["started_at"] + (t - run["started_at"]))
    with server.client() as c:
        rows = raw_rows(c, "snail-1", "position", other["started_at"], min(compare["t"], other["ended_at"]))
    assert compare["shown"]["snail-1"]["ts"] == rows[-1]["ts"]
    assert compare["shown"]["snail-1"]["x"] == pytest.approx(rows[-1]["data"]["x"])
    legend = page.get_by_test_id("replay-legend")
    assert legend.locator("li[data-run=this]").count() == 3
    assert legend.locator("li[data-run=compare]").count() == 1
    assert "second trial (dashed)" in legend.locator("li[data-run=compare]").inner_text()
    assert axe_violations(page) == []

    # delete: two presses (admin), then it is gone
    page.get_by_test_id("run-delete").click()
    page.get_by_test_id("run-delete").filter(has_text="again").wait_for()
    page.get_by_test_id("run-delete").click()
    page.wait_for_url("**/runs")
    with server.client() as c:
        assert c.get(f"/api/runs/{run_id}").status_code == 404


def test_the_start_form_lists_the_fleet_when_the_runs_page_is_opened_directly(server, fleet, page_factory):
    """Opened by its address (a bookmark, a reload), the page is built before the fleet arrives over the live
    connection: the robots to record fill in when it does."""
    page, rec = open_page(page_factory, "/runs")
    page.wait_for_function(
        "ids => ids.every((id) => [...document.querySelectorAll('[data-testid=run-robots] option')]"
        ".some((o) => o.value === id))",
        arg=["snail-1", "snail-2"],
    )
    assert not rec.console_errors, rec.console_errors
