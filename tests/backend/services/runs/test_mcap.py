"""The MCAP writer puts a robot's messages on the server's clock: log time = the robot's stamp plus the
offset it measured (server minus robot), publish time = the robot's own stamp; a step down of the offset
never makes a channel's log times go back. Synthetic offsets of seconds, so that the sign shows."""

from __future__ import annotations

import io
from collections import namedtuple
from typing import Any

import orjson
import pytest
from mcap.reader import make_reader

from backend.services.runs.mcap import RunSource, write_run

Row = namedtuple("Row", "robot_id stream ts seq recv_ts payload")


def _export(
    rows: list[Row], offsets: dict[str, list[tuple[float, float]]]
) -> tuple[dict[str, list[tuple[int, int]]], dict[str, str]]:
    """(topic -> [(log time, publish time)], the ``clock`` metadata record) of the file written."""
    out = io.BytesIO()
    source = RunSource(telemetry=rows, frames=[], events=[], commands=[], markers=[], clock_offsets=offsets)
    run: dict[str, Any] = {"id": 1, "name": "clock", "robots": ["r1", "r2"], "started_at": 100.0, "ended_at": 120.0}
    write_run(out, run, source, {"version": 1}, lambda frame: None)
    times: dict[str, list[tuple[int, int]]] = {}
    for _, channel, message in make_reader(io.BytesIO(out.getvalue())).iter_messages(log_time_order=False):
        times.setdefault(channel.topic, []).append((message.log_time, message.publish_time))
    meta = {m.name: m.metadata for m in make_reader(io.BytesIO(out.getvalue())).iter_metadata()}
    return times, meta["clock"]


def _pose(rid: str, ts: float, seq: int) -> Row:
    return Row(rid, "position", ts, seq, ts + 2.5, orjson.dumps({"x": 0.0, "y": 0.0, "yaw": 0.0}))


def test_log_times_are_the_robots_stamps_moved_by_its_measured_offset() -> None:
    # r1's clock is 2.5 s behind the server's, then (after a re-sync at 105 s) 2.4 s behind; r2 never measured
    offsets = {"r1": [(99.0, 2.5), (105.0, 2.4)]}
    rows = [_pose("r1", 100.0 + 0.5 * k, k) for k in range(20)] + [_pose("r2", 100.0, 0)]
    rows.append(Row("r1", "imu", 101.0, 0, 103.5, orjson.dumps({"ax": 0.1})))
    rows.sort(key=lambda r: r.ts)
    times, clock = _export(rows, offsets)
    poses = times["/r1/position"]
    assert [p for _, p in poses] == [round((100.0 + 0.5 * k) * 1e9) for k in range(20)]  # the robot's own stamps
    assert poses[0][0] == round(102.5 * 1e9)  # 100.0 + 2.5: the offset measured before the run
    assert poses[10][0] == round(107.4 * 1e9)  # 105.0 + 2.4: after the re-sync
    assert times["/r1/imu"] == [(round(103.5 * 1e9), round(101.0 * 1e9))]  # every stream, not only poses
    assert times["/r2/position"] == [(round(100.0 * 1e9), round(100.0 * 1e9))]  # unmeasured: as stamped
    assert clock["r1"] == "offset median 2500.000 ms over 2 samples"
    assert clock["r2"] == "no offset measured: the robot's own ts"


def test_a_step_down_of_the_offset_never_sends_a_channel_back_in_time() -> None:
    # a re-sync finds the robot 0.3 s less behind: corrected stamps just after it fall before the last one
    offsets = {"r1": [(99.0, 2.7), (105.0, 2.4)]}
    rows = [_pose("r1", 104.0 + 0.1 * k, k) for k in range(20)]
    log_times = [log for log, _ in _export(rows, offsets)[0]["/r1/position"]]
    corrected = [round((104.0 + 0.1 * k + (2.7 if 104.0 + 0.1 * k < 105.0 else 2.4)) * 1e9) for k in range(20)]
    assert corrected != sorted(corrected), "the offsets chosen do not step back: nothing would be tested"
    assert log_times == sorted(log_times)
    assert log_times[-1] == corrected[-1]  # once past the step, the corrected time again
    assert log_times[0] == pytest.approx(corrected[0])
