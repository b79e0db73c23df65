"""A run as MCAP, written with the ``mcap`` library in Foxglove's well-known schemas (protobuf), so that
Foxglove, Lichtblick and PlotJuggler draw it with no setup.

Topics ``/{robot}/{stream}``: ``position`` as ``foxglove.PoseInFrame`` in the ``pool`` frame, camera
frames as ``foxglove.CompressedImage`` (``/{robot}/camera``), AprilTag detections as
``foxglove.ImageAnnotations`` on the camera's time stamps (``/{robot}/camera/annotations``), events and
markers as ``foxglove.Log`` (``/events``, ``/markers``); every other stream, and the commands, as JSON with
a JSON schema. Log time is the robot's time stamp (what it measured, when). The run's metadata goes in
metadata records, the site as an attachment. Everything is read and written one message at a time.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import IO, Any

import orjson
from foxglove_schemas_protobuf.Log_pb2 import Log

from backend.services.runs.frames import StoredFrame
from backend.services.runs.mcap_writer import McapRunWriter, loads_json


@dataclass(frozen=True, slots=True)
class RunSource:
    """Where a run's messages come from (each an iterator in time order)."""

    telemetry: Iterable[Any]  # rows (robot_id, stream, ts, seq, payload)
    frames: Iterable[StoredFrame]
    events: Iterable[Any]  # rows (id, ts, kind, robot_id, detail)
    commands: Iterable[Any]  # rows (id, robot_id, command, args, source, ts, ttl_s, status, reason)
    markers: list[dict[str, Any]]
    #: the latest lighthouse_geometry payload before the run (base stations are published once, retained)
    geometry: Any = None
    #: robot -> [(robot ts, offset s)] from its health stream (store.runs.clock_offsets): log times are the
    #: robot's stamps moved onto the server's clock
    clock_offsets: dict[str, list[tuple[float, float]]] = field(default_factory=dict)


def _level(kind: str) -> int:
    if kind in ("estop", "run_frames_stopped", "offline"):
        return Log.WARNING if kind != "estop" else Log.ERROR
    return Log.INFO


def write_run(
    out: IO[bytes],
    run: dict[str, Any],
    source: RunSource,
    site: dict[str, Any],
    read_frame: Callable[[StoredFrame], bytes | None],
    on_message: Callable[[], None] | None = None,
) -> dict[str, int]:
    """Write a whole run, merged in time order; returns the message count per topic."""
    w = McapRunWriter(out)
    w.set_clock_offsets(source.clock_offsets)
    stations = list(site.get("base_stations") or [])
    if not stations and source.geometry is not None:  # the robots' own, as published before the run
        stations = list(loads_json(source.geometry).get("base_stations") or [])
    begin = float(run.get("exported_from") or run["started_at"])  # a range starts later than the run
    w.transforms(begin, stations, list(site.get("tags") or []))
    tagged: list[Iterator[tuple[float, int, Any]]] = [
        ((r.ts, 0, r) for r in source.telemetry),
        ((f.ts, 1, f) for f in source.frames),
        ((e.ts, 2, e) for e in source.events),
        ((c.ts, 3, c) for c in source.commands),
        ((m["ts"], 4, m) for m in source.markers),
    ]
    for ts, kind, item in heapq.merge(*tagged, key=lambda t: (t[0], t[1])):
        if kind == 0:
            w.telemetry(item.robot_id, item.stream, ts, item.seq, item.payload, item.recv_ts)
        elif kind == 1:
            jpeg = read_frame(item)
            if jpeg is not None:
                w.frame(item, jpeg)
        elif kind == 2:
            detail = loads_json(item.detail) or {}
            who = f"{item.robot_id}: " if item.robot_id else ""
            w.log("/events", ts, _level(item.kind), item.kind, who + orjson.dumps(detail).decode())
        elif kind == 3:
            w.command(item)
        else:
            who = f"{item['robot_id']}: " if item["robot_id"] else ""
            w.log("/markers", ts, Log.INFO, "marker", who + item["text"])
        if on_message is not None:
            on_message()
    w.metadata("run", _run_metadata(run))
    w.metadata("clock", clock_metadata(run.get("robots") or [], source.clock_offsets))
    agents: dict[str, Any] = dict(run.get("agents") or {})
    w.metadata("agents", {rid: orjson.dumps(info).decode() for rid, info in agents.items()})
    for rid, info in agents.items():  # one record per agent, its configuration flattened (readable as is)
        w.metadata(f"agent/{rid}", agent_metadata(info))
    w.attachment("site.json", "application/json", orjson.dumps(site), begin)
    w.finish()
    return w.counts


def clock_metadata(robots: list[str], offsets: dict[str, list[tuple[float, float]]]) -> dict[str, str]:
    """How each robot's log times were made: its median measured offset (ms), or that it had none."""
    out = {"log_time": "the robot's ts plus its measured clock offset (server minus robot) at that moment"}
    for rid in robots:
        samples = sorted(o for _, o in offsets.get(rid, []))
        out[rid] = (
            f"offset median {samples[len(samples) // 2] * 1000:.3f} ms over {len(samples)} samples"
            if samples
            else "no offset measured: the robot's own ts"
        )
    return out


def flatten(value: Any, prefix: str = "", out: dict[str, str] | None = None) -> dict[str, str]:
    """``{"a": {"b": [1]}}`` -> ``{"a.b.0": "1"}``: MCAP metadata holds strings only."""
    out = {} if out is None else out
    if isinstance(value, dict) and value:
        for k, v in value.items():
            flatten(v, f"{prefix}.{k}" if prefix else str(k), out)
    elif isinstance(value, list) and value:
        for i, v in enumerate(value):
            flatten(v, f"{prefix}.{i}" if prefix else str(i), out)
    elif prefix:
        out[prefix] = "" if value is None else value if isinstance(value, str) else orjson.dumps(value).decode()
    return out


def agent_metadata(info: dict[str, Any]) -> dict[str, str]:
    """An agent's versions and its effective configuration (``config.*``, secrets removed by the agent and
    again by the server) as one metadata record."""
    out = {k: "" if info.get(k) is None else str(info[k]) for k in ("agent_version", "protocol_version", "boot")}
    out["config_published"] = "false" if info.get("config") is None else "true"
    flatten(info.get("config") or {}, "config", out)
    if info.get("config_changes"):
        out["config_changes"] = orjson.dumps(info["config_changes"]).decode()
    return out


def _run_metadata(run: dict[str, Any]) -> dict[str, str]:
    keys = (
        "id",
        "name",
        "notes",
        "operator",
        "started_at",
        "ended_at",
        "exported_from",
        "exported_until",
        "site_version",
        "frame_rate",
    )
    out = {k: "" if run.get(k) is None else str(run[k]) for k in keys}
    out["tags"] = orjson.dumps(run.get("tags") or []).decode()
    out["robots"] = orjson.dumps(run.get("robots") or []).decode()
    out["running"] = "true" if run.get("ended_at") is None else "false"
    return out
