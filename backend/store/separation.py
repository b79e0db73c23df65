"""What the separation figures (backend/services/runs/separation.py) read: each robot's stored ``position``
samples and ``avoidance`` messages over a stretch, bounded: a robot with more positions than its share is
thinned in the database (every k-th row), and at most a cap of avoidance messages is read."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import orjson
from sqlalchemy import Engine, text

from backend.store.runs import clock_offsets

_COUNT = text(
    "SELECT COUNT(*) FROM telemetry WHERE robot_id = :r AND stream = 'position' AND ts >= :a AND ts <= :b "
    "AND x IS NOT NULL AND y IS NOT NULL"
)
_ALL = text(
    "SELECT ts, x, y FROM telemetry WHERE robot_id = :r AND stream = 'position' AND ts >= :a AND ts <= :b "
    "AND x IS NOT NULL AND y IS NOT NULL ORDER BY ts, seq"
)
# every k-th row, counted in the database: a long run never comes into memory whole
_THINNED = text(
    "SELECT ts, x, y FROM (SELECT ts, seq, x, y, ROW_NUMBER() OVER (ORDER BY ts, seq) AS n FROM telemetry "
    "WHERE robot_id = :r AND stream = 'position' AND ts >= :a AND ts <= :b AND x IS NOT NULL AND y IS NOT NULL"
    ") AS t WHERE (n - 1) % :k = 0 ORDER BY ts, seq"
)
_AVOIDANCE = text(
    "SELECT ts, payload FROM telemetry WHERE robot_id = :r AND stream = :s AND ts >= :a AND ts <= :b "
    "ORDER BY ts, seq LIMIT :n"
)


@dataclass
class RobotSamples:
    """One robot's positions (time order, server clock) and avoidance messages over the stretch."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    #: every ``step``-th stored position was read
    step: int = 1
    avoidance: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    avoidance_truncated: bool = False


def _shift(ts: np.ndarray, offsets: list[tuple[float, float]]) -> np.ndarray:
    """Robot stamps onto the server's clock: plus the offset it measured last at or before each stamp (the
    first one before it for earlier stamps), as the MCAP export does (docs/runs.md); none measured: as is."""
    if not offsets or ts.size == 0:
        return ts
    at = np.array([o[0] for o in offsets])
    off = np.array([o[1] for o in offsets])
    i = np.clip(np.searchsorted(at, ts, side="right") - 1, 0, len(off) - 1)
    return ts + off[i]


def read_samples(
    engine: Engine, robots: list[str], start: float, end: float, cap: int, avoidance_cap: int, stream: str
) -> dict[str, RobotSamples]:
    """Each robot's positions (at most about ``cap``: thinned evenly beyond it) and its first
    ``avoidance_cap`` messages of ``stream``, their stamps moved onto the server's clock."""
    offsets = clock_offsets(engine, robots, start, end)
    out: dict[str, RobotSamples] = {}
    with engine.connect() as conn:
        for rid in robots:
            count = int(conn.execute(_COUNT, {"r": rid, "a": start, "b": end}).scalar_one())
            step = max(1, math.ceil(count / max(1, cap)))
            params = {"r": rid, "a": start, "b": end, "k": step}
            rows = conn.execute(_ALL if step == 1 else _THINNED, params).all()
            arr = np.array([(r[0], r[1], r[2]) for r in rows], dtype=float).reshape(-1, 3)
            t = _shift(arr[:, 0], offsets.get(rid, []))
            order = np.argsort(t, kind="stable")
            samples = RobotSamples(t=t[order], x=arr[order, 1], y=arr[order, 2], step=step)
            q = {"r": rid, "s": stream, "a": start, "b": end, "n": avoidance_cap + 1}
            msgs = conn.execute(_AVOIDANCE, q).all()
            samples.avoidance_truncated = len(msgs) > avoidance_cap
            avoidance_ts = _shift(np.array([float(m[0]) for m in msgs[:avoidance_cap]]), offsets.get(rid, []))
            for ts, m in zip(avoidance_ts.tolist(), msgs[:avoidance_cap], strict=True):
                data = orjson.loads(m[1]) if isinstance(m[1], (str, bytes)) else m[1]
                if isinstance(data, dict):
                    samples.avoidance.append((float(ts), data))
            out[rid] = samples
    return out
