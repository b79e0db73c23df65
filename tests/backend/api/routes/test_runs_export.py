"""A run exported as MCAP, Parquet and zip, read back as an analyst would (the mcap reader, pyarrow,
DuckDB), against what the robots sent as the API returns it; camera frames kept at the run's rate; the
frame store's quota."""

from __future__ import annotations

import base64
import bisect
import inspect
import io
import itertools
import json
import re
import time
import zipfile
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import duckdb
import pyarrow.parquet as pq
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.reader import make_reader

from backend.store.runs import detections_of_frame
from tests.support.procs import ServerProcess, wait_for
from tests.support.runs import raw_rows, wait_online, wait_stored_past

ROBOTS = ["exp-a", "exp-b", "exp-c"]


def _record(c: Any, seconds: float) -> dict[str, Any]:
    run = c.post("/api/runs", json={"name": "export trial", "tags": ["export"], "robots": ROBOTS}).json()
    c.post("/api/robots/exp-a/commands", json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 1.0}})
    time.sleep(seconds / 2)
    c.post(f"/api/runs/{run['id']}/markers", json={"text": "halfway", "robot_id": "exp-b"})
    time.sleep(seconds / 2)
    r = c.post(f"/api/runs/{run['id']}/stop")
    assert r.status_code == 200, r.text
    return r.json()


def _download(c: Any, run_id: int, fmt: str) -> tuple[bytes, Any]:
    with c.stream("GET", f"/api/runs/{run_id}/export", params={"format": fmt}) as r:
        assert r.status_code == 200, r.read()
        assert "content-length" not in r.headers  # streamed, not built in memory first
        return r.read(), r.headers


@pytest.fixture
def recorded(server, spawn_agent):
    for i, rid in enumerate(ROBOTS):
        spawn_agent(rid, "--camera", f"--start-pose={i - 1},0,0")
    with server.client() as c:
        wait_online(c, ROBOTS)
        wait_for(lambda: all(c.get(f"/api/robots/{r}/camera/latest.jpg").status_code == 200 for r in ROBOTS), 20)
        run = _record(c, 8.0)
        wait_stored_past(c, ROBOTS, run["ended_at"])
        yield c, run


def test_mcap_export_matches_what_the_robots_sent(recorded):
    c, run = recorded
    data, headers = _download(c, run["id"], "mcap")
    assert headers["x-fleet-run-running"] == "false"
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary is not None
    schema_of = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    for rid in ROBOTS:
        assert schema_of[f"/{rid}/position"] == "foxglove.PoseInFrame"
        assert schema_of[f"/{rid}/camera"] == "foxglove.CompressedImage"
        assert schema_of[f"/{rid}/imu"].startswith("fleet.")  # other streams: JSON with a JSON schema
    assert schema_of["/markers"] == "foxglove.Log" and schema_of["/events"] == "foxglove.Log"
    # the base stations the robots published (retained, before the run) as frames under "pool"
    assert schema_of["/tf"] == "foxglove.FrameTransforms"
    geometry = c.get("/api/robots/exp-a/telemetry", params={"stream": "lighthouse_geometry", "raw": "true"}).json()
    stations = geometry["points"][-1]["data"]["base_stations"]
    tf = FrameTransforms()
    first_tf = next(m for _, ch, m in make_reader(io.BytesIO(data)).iter_messages(topics=["/tf"]))
    tf.ParseFromString(first_tf.data)
    assert first_tf.log_time == round(run["started_at"] * 1e9)
    assert [t.child_frame_id for t in tf.transforms] == [f"base_station_{b['id']}" for b in stations]
    assert all(t.parent_frame_id == "pool" for t in tf.transforms)
    assert [t.translation.x for t in tf.transforms] == pytest.approx([b["position"][0] for b in stations])

    poses: dict[str, list[tuple[int, PoseInFrame]]] = defaultdict(list)
    last_time: dict[str, int] = {}
    frames: dict[str, int] = defaultdict(int)
    markers = []
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        # time never goes back within a channel
        assert message.log_time >= last_time.get(channel.topic, 0), channel.topic
        last_time[channel.topic] = message.log_time
        if schema.name == "foxglove.PoseInFrame":
            pose = PoseInFrame()
            pose.ParseFromString(message.data)
            poses[channel.topic.split("/")[1]].append((message.log_time, pose))
        elif schema.name == "foxglove.CompressedImage":
            img = CompressedImage()
            img.ParseFromString(message.data)
            assert img.format == "jpeg" and img.data[:2] == b"\xff\xd8"
            frames[channel.topic.split("/")[1]] += 1
        elif channel.topic == "/markers":
            markers.append(message)
    assert len(markers) == 1
    for rid in ROBOTS:
        rows = raw_rows(c, rid, "position", run["started_at"], run["ended_at"])
        assert len(rows) > 50
        assert len(poses[rid]) == len(rows)  # exactly as many as the API returns for the run
        on_server_clock = _robot_time(c, rid, run)
        for (log_time, pose), row in zip(poses[rid], rows, strict=True):
            # log time: the robot's stamp on the server's clock (plus its measured offset at that moment)
            assert log_time == on_server_clock(row["ts"])
            assert pose.pose.position.x == pytest.approx(row["data"]["x"])
            assert pose.pose.position.y == pytest.approx(row["data"]["y"])
            assert pose.frame_id == "pool"
        assert frames[rid] > 0
        # AprilTag detections: one ImageAnnotations per apriltag message, on the camera's time stamps
        tags = raw_rows(c, rid, "apriltag", run["started_at"], run["ended_at"])
        annotations = [
            m for _, ch, m in make_reader(io.BytesIO(data)).iter_messages(topics=[f"/{rid}/camera/annotations"])
        ]
        assert len(annotations) == len(tags)
        if tags:
            assert schema_of[f"/{rid}/camera/annotations"] == "foxglove.ImageAnnotations"
            assert [m.log_time for m in annotations] == [on_server_clock(t["ts"]) for t in tags]
    assert sum(frames.values()) == run["frames"]
    assert any(raw_rows(c, rid, "apriltag", run["started_at"], run["ended_at"]) for rid in ROBOTS)
    meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert meta["run"]["name"] == "export trial" and json.loads(meta["run"]["robots"]) == ROBOTS
    assert set(meta["agents"]) == set(ROBOTS)
    for rid in ROBOTS:  # each agent's versions and its effective configuration, as it published them
        agent = meta[f"agent/{rid}"]
        assert agent["config_published"] == "true" and agent["agent_version"] == run["agents"][rid]["agent_version"]
        assert agent["config.robot_id"] == rid and agent["config.simulate"] == "true"
        assert agent["config.sensors.0.type"] == "position" and agent["config.motors.type"] == "sim"
        assert json.loads(meta["agents"][rid])["config"]["camera"] is True
    for rid in ROBOTS:  # how the log times were made, per robot
        assert meta["clock"][rid].startswith("offset median"), meta["clock"]
    attachments = {a.name: a for a in reader.iter_attachments()}
    assert json.loads(attachments["site.json"].data)["version"] == run["site_version"]


def _robot_time(c: Any, rid: str, run: dict[str, Any]) -> Callable[[float], int]:
    """The exporter's log time of a robot's stamp, from what the API says the robot measured: its health
    stream's clock_offset_ms (server minus robot) last reported at or before the stamp (the last one before
    the run for the first messages)."""
    health = raw_rows(c, rid, "health", run["started_at"] - 5, run["ended_at"])
    samples = [
        (h["ts"], h["data"]["clock_offset_ms"] / 1000) for h in health if h["data"].get("clock_offset_ms") is not None
    ]
    before = [s for s in samples if s[0] < run["started_at"]]
    samples = before[-1:] + [s for s in samples if s[0] >= run["started_at"]]
    assert samples, f"{rid} reported no clock offset"
    times = [t for t, _ in samples]

    def at(ts: float) -> int:
        return round((ts + samples[max(0, bisect.bisect_right(times, ts) - 1)][1]) * 1e9)

    return at


def test_a_range_exports_only_that_stretch_and_bad_ranges_are_refused(recorded):
    c, run = recorded
    start, end = run["started_at"], run["ended_at"]
    marker_ts = c.get(f"/api/runs/{run['id']}").json()["markers"][0]["ts"]
    lo, hi = marker_ts + 0.5, end - 1.0  # after the marker: it must be left out
    with c.stream("GET", f"/api/runs/{run['id']}/export", params={"format": "mcap", "from": lo, "to": hi}) as r:
        assert r.status_code == 200, r.read()
        data = r.read()
        assert r.headers["x-fleet-range"] == f"{lo!r},{hi!r}"
        assert re.search(r"run-\d+-[0-9.]+s-[0-9.]+s\.mcap", r.headers["content-disposition"])
    reader = make_reader(io.BytesIO(data))
    poses: dict[str, int] = defaultdict(int)
    frames = 0
    topics = set()
    for _, channel, message in reader.iter_messages():
        topics.add(channel.topic)
        # the range is of the stamps (a robot's own, its message's publish time; its log time is moved onto
        # the server's clock by its measured offset)
        assert round(lo * 1e9) <= message.publish_time <= round(hi * 1e9), channel.topic
        if channel.topic.endswith("/position"):
            poses[channel.topic.split("/")[1]] += 1
        elif channel.topic.endswith("/camera"):
            frames += 1
    assert "/markers" not in topics  # the marker lies before the range
    for rid in ROBOTS:
        assert poses[rid] == len(raw_rows(c, rid, "position", lo, hi)) > 5
    assert 0 < frames < run["frames"]
    meta = {m.name: m.metadata for m in make_reader(io.BytesIO(data)).iter_metadata()}
    assert float(meta["run"]["exported_from"]) == lo and float(meta["run"]["exported_until"]) == hi

    # the zip's run.json says which stretch it holds; Parquet holds the same rows
    bundle, _ = _download_range(c, run["id"], "zip", start, marker_ts + 0.5)
    zf = zipfile.ZipFile(io.BytesIO(bundle))
    meta_json = json.loads(zf.read("run.json"))["run"]
    assert meta_json["range"] is True and meta_json["exported_until"] == marker_ts + 0.5
    assert [m["text"] for m in json.loads(zf.read("run.json"))["markers"]] == ["halfway"]
    table = pq.read_table(io.BytesIO(zf.read("parquet/position.parquet")))
    assert table.num_rows == sum(len(raw_rows(c, rid, "position", start, marker_ts + 0.5)) for rid in ROBOTS)

    url = f"/api/runs/{run['id']}/export"
    for params, code in (
        ({"from": start - 10}, "from_outside_run"),
        ({"from": end + 1}, "from_outside_run"),
        ({"to": end + 10}, "to_outside_run"),
        ({"to": start - 1}, "to_outside_run"),
        ({"from": hi, "to": lo}, "from_not_before_to"),
        ({"from": lo, "to": lo}, "from_not_before_to"),
    ):
        r = c.get(url, params={"format": "mcap", **params})
        assert r.status_code == 422 and r.json()["code"] == code, (params, r.text)
    for bad in ({"from": "soon"}, {"to": "nan"}, {"from": "inf"}):
        r = c.get(url, params=bad)
        assert r.status_code == 422 and r.json()["code"] == "validation_error", (bad, r.text)
    assert c.get("/api/runs/999999/export", params={"from": lo, "to": hi}).status_code == 404


def _download_range(c: Any, run_id: int, fmt: str, lo: float, hi: float) -> tuple[bytes, Any]:
    with c.stream("GET", f"/api/runs/{run_id}/export", params={"format": fmt, "from": lo, "to": hi}) as r:
        assert r.status_code == 200, r.read()
        return r.read(), r.headers


def test_frames_are_kept_at_the_runs_rate(recorded):
    _, run = recorded
    duration = run["ended_at"] - run["started_at"]
    per_robot = run["frames"] / len(ROBOTS)
    # the camera sends 10 fps; the run keeps 5 a second (not more, and not far fewer)
    assert 5 * duration * 0.6 <= per_robot <= 5 * duration + 2, (per_robot, duration)
    assert run["frame_bytes"] > 0 and not run["frames_stopped"]


def test_parquet_export_has_one_typed_table_per_stream(recorded, tmp_path: Path):
    c, run = recorded
    data, _ = _download(c, run["id"], "parquet")
    zf = zipfile.ZipFile(io.BytesIO(data))
    names = sorted(zf.namelist())
    assert "position.parquet" in names and "imu.parquet" in names
    for name in names:
        (tmp_path / name).write_bytes(zf.read(name))
    table = pq.read_table(tmp_path / "position.parquet")
    assert table.schema.field("ts").type == "double" and table.schema.field("seq").type == "int64"
    assert table.schema.field("x").type == "double" and table.schema.field("robot_id").type == "string"
    # the server's receive time beside the robot's, for every row stored live
    assert table.schema.field("recv_ts").type == "double" and table.column("recv_ts").null_count == 0
    for name in names:
        stream = name.removesuffix(".parquet")
        expected = sum(len(raw_rows(c, rid, stream, run["started_at"], run["ended_at"])) for rid in ROBOTS)
        got = duckdb.sql(f"SELECT count(*) FROM read_parquet('{tmp_path / name}')").fetchall()
        assert got == [(expected,)], stream  # DuckDB reads it as it is
    rows = raw_rows(c, "exp-a", "position", run["started_at"], run["ended_at"])
    position = tmp_path / "position.parquet"
    got_rows = duckdb.sql(
        f"SELECT ts, seq, x, y FROM read_parquet('{position}') WHERE robot_id = 'exp-a' ORDER BY ts, seq"
    ).fetchall()
    assert [(r["ts"], r["seq"], r["data"]["x"], r["data"]["y"]) for r in rows] == got_rows


def test_zip_bundle_holds_everything(recorded):
    c, run = recorded
    data, _ = _download(c, run["id"], "zip")
    zf = zipfile.ZipFile(io.BytesIO(data))
    names = zf.namelist()
    meta = json.loads(zf.read("run.json"))
    assert meta["run"]["id"] == run["id"] and [m["text"] for m in meta["markers"]] == ["halfway"]
    assert meta["summary"]["messages_total"] > 0
    for rid in ROBOTS:  # the agents' versions and configs
        agent = meta["run"]["agents"][rid]
        assert agent["agent_version"] and agent["protocol_version"] == 1
        assert agent["config"]["robot_id"] == rid and agent["config"]["broker"].startswith("mqtt://")
        assert {s["type"] for s in agent["config"]["sensors"]} >= {"position", "camera", "apriltag"}
    assert f"run-{run['id']}.mcap" in names and "parquet/position.parquet" in names
    jpegs = [n for n in names if n.startswith("frames/") and n.endswith(".jpg")]
    assert len(jpegs) == run["frames"]
    assert {n.split("/")[1] for n in jpegs} == set(ROBOTS)
    assert all(zf.read(n)[:2] == b"\xff\xd8" for n in itertools.islice(jpegs, 20))
    summary = make_reader(io.BytesIO(zf.read(f"run-{run['id']}.mcap"))).get_summary()
    assert summary is not None and summary.statistics is not None and summary.statistics.message_count > 0


def test_a_running_run_exports_up_to_now_and_says_so(server, spawn_agent):
    spawn_agent("live-a")
    with server.client() as c:
        wait_online(c, ["live-a"])
        run = c.post("/api/runs", json={"name": "still going", "robots": ["live-a"]}).json()
        time.sleep(1.5)
        data, headers = _download(c, run["id"], "mcap")
        assert headers["x-fleet-run-running"] == "true"
        reader = make_reader(io.BytesIO(data))
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert meta["run"]["running"] == "true" and float(meta["run"]["exported_until"]) > run["started_at"]
        assert sum(1 for _ in reader.iter_messages(topics=["/live-a/position"])) > 5


def test_frames_stop_at_the_quota_and_telemetry_goes_on(broker, database_url, workdir, spawn_agent):
    server = ServerProcess(broker, database_url, workdir, FLEET_RUNS_FRAMES_QUOTA_MB="0.05")
    server.start()
    try:
        spawn_agent("quota-a", "--camera", "--start-pose=1,0,0")
        with server.client() as c:
            wait_online(c, ["quota-a"])
            run = c.post("/api/runs", json={"name": "full disk", "robots": ["quota-a"]}).json()
            rid = run["id"]

            def stopped() -> dict[str, Any] | None:
                detail = c.get(f"/api/runs/{rid}").json()
                return detail if detail["frames_stopped"] else None

            detail = wait_for(stopped, 20, what="frames stopped at the quota")
            assert "quota" in detail["frames_stopped_reason"]
            alarms = c.get("/api/alarms", params={"state": "open"}).json()
            assert any(a["kind"] == "frames_quota" for a in alarms)
            before = detail["summary"]["messages_total"]
            time.sleep(1.5)
            after = c.get(f"/api/runs/{rid}").json()["summary"]["messages_total"]
            assert after > before + 10  # telemetry is still recorded
            done = c.post(f"/api/runs/{rid}/stop").json()
            assert 0 < done["frame_bytes"] <= 0.05 * 1024 * 1024
            assert done["frames_stopped"]
    finally:
        server.stop()


def test_the_replay_camera_answers_the_frame_at_or_before_a_time(recorded):
    """GET /api/runs/{id}/frames: the stored frame nearest at or before ``at`` (the same bytes the export
    holds) with the detections of that very frame; bad input is a clear 404 / 422."""
    c, run = recorded
    data, _ = _download(c, run["id"], "mcap")
    # the robot whose camera saw the most tags (the overlay has something to draw)
    # a frame's detections are stored a little after the frame, so those of the run's last frames can come
    # after its end: read as far as the server looks for them (detections_of_frame's window)
    window_s = inspect.signature(detections_of_frame).parameters["window_s"].default
    seen = {rid: raw_rows(c, rid, "apriltag", run["started_at"], run["ended_at"] + window_s) for rid in ROBOTS}
    rid = max(ROBOTS, key=lambda r: sum(bool(t["data"]["detections"]) for t in seen[r]))
    tags = {t["data"]["frame_seq"]: t["data"] for t in seen[rid]}
    frames = [  # when each was taken, on the robot's clock: the publish time (the log time is the server's)
        (m.publish_time / 1e9, m.sequence, CompressedImage.FromString(m.data).data)
        for _, _, m in make_reader(io.BytesIO(data)).iter_messages(topics=[f"/{rid}/camera"])
    ]
    assert len(frames) > 10
    # when each stored frame was taken: the same frames, in time order
    times = c.get(f"/api/runs/{run['id']}/frames/times", params={"robot": rid}).json()
    assert [(round(ts * 1e9), seq) for ts, seq in times["frames"]] == [(round(ts * 1e9), seq) for ts, seq, _ in frames]
    with_tags = 0
    for k in (1, len(frames) // 2, len(frames) - 1):
        ts, seq, jpeg = frames[k]
        # between this frame and the next, and exactly on it: this frame
        for at in (ts, (ts + frames[k + 1][0]) / 2 if k + 1 < len(frames) else run["ended_at"]):
            r = c.get(f"/api/runs/{run['id']}/frames", params={"robot": rid, "at": repr(at)})
            assert r.status_code == 200, r.text
            body = r.json()
            assert (body["ts"], body["frame_seq"]) == (pytest.approx(ts, abs=1e-6), seq)
            assert base64.b64decode(body["jpeg_base64"]) == jpeg
            assert body["detections"] == tags.get(seq)
            with_tags += bool((body["detections"] or {}).get("detections"))
        raw = c.get(f"/api/runs/{run['id']}/frames", params={"robot": rid, "at": repr(ts), "format": "jpeg"})
        assert raw.status_code == 200 and raw.headers["content-type"] == "image/jpeg" and raw.content == jpeg
        assert int(raw.headers["x-fleet-frame-seq"]) == seq
    assert with_tags > 0  # the simulated camera sees tags: the overlay has something to draw

    # bad input
    def refused(params: dict[str, str], run_id: int = run["id"]) -> tuple[int, str]:
        r = c.get(f"/api/runs/{run_id}/frames", params=params)
        return r.status_code, r.json().get("code", "")

    mid = repr((run["started_at"] + run["ended_at"]) / 2)
    assert refused({"robot": rid, "at": mid}, 999999) == (404, "unknown_run")
    assert refused({"robot": "snail-9", "at": mid}) == (422, "robot_not_in_run")
    assert refused({"robot": rid, "at": repr(run["ended_at"] + 5)}) == (422, "at_outside_run")
    assert refused({"robot": rid, "at": repr(run["started_at"] - 5)}) == (422, "at_outside_run")
    assert refused({"robot": "exp/a", "at": mid})[0] == 422
    assert refused({"robot": rid, "at": "soon"})[0] == 422
    assert refused({"robot": rid})[0] == 422
    # a run that keeps no frames: nothing to show, said so
    bare = c.post("/api/runs", json={"name": "no frames", "robots": [rid], "frame_rate": 0}).json()
    bare = c.post(f"/api/runs/{bare['id']}/stop").json()
    at = repr((bare["started_at"] + bare["ended_at"]) / 2)
    assert refused({"robot": rid, "at": at}, bare["id"]) == (404, "no_frame")
    assert c.get(f"/api/runs/{bare['id']}/frames/times", params={"robot": rid}).json()["frames"] == []
    r = c.get(f"/api/runs/{run['id']}/frames/times", params={"robot": "snail-9"})
    assert (r.status_code, r.json()["code"]) == (422, "robot_not_in_run")
