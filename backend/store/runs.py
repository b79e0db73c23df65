"""Runs and markers in the database, and the reads a run's summary and exports are made of.

Writes return ops for the writer thread (BatchWriter.submit); reads block (call them in a thread). A run's
data is read from the tables that hold it (telemetry, commands, events, alarms) by its robots and time
range: nothing is copied, so a run is as complete as what was stored.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import orjson
from shapely import LineString
from sqlalchemy import Connection, Engine, bindparam, delete, insert, select, text, update

from backend.models import MarkerRow, RunRow
from backend.store.run_reads import iter_telemetry

#: gaps listed in a summary (the missing total counts all of them)
MAX_GAPS_LISTED = 200
#: positions per piece of a trajectory measured at once (bounded memory for long runs)
DISTANCE_CHUNK = 5000


def index_of(values: list[str]) -> str:
    """``|a|b|``: one LIKE ``%|a|%`` finds a value on SQLite and PostgreSQL alike."""
    return "|" + "".join(f"{v}|" for v in values)


# --- writes -----------------------------------------------------------------------------------------------


def insert_run(values: dict[str, Any]) -> Callable[[Connection], int]:
    def op(conn: Connection) -> int:
        return int(conn.execute(insert(RunRow).values(**values).returning(RunRow.id)).scalar_one())

    return op


def update_run(run_id: int, values: dict[str, Any]) -> Callable[[Connection], int]:
    def op(conn: Connection) -> int:
        return int(conn.execute(update(RunRow).where(RunRow.id == run_id).values(**values)).rowcount or 0)

    return op


def end_run(run_id: int, ended_at: float, values: dict[str, Any]) -> Callable[[Connection], int]:
    """Close a run still open (0 when it was already closed: the first stop wins)."""

    def op(conn: Connection) -> int:
        stmt = update(RunRow).where(RunRow.id == run_id, RunRow.ended_at.is_(None))
        return int(conn.execute(stmt.values(ended_at=ended_at, **values)).rowcount or 0)

    return op


def insert_marker(values: dict[str, Any]) -> Callable[[Connection], int]:
    def op(conn: Connection) -> int:
        return int(conn.execute(insert(MarkerRow).values(**values).returning(MarkerRow.id)).scalar_one())

    return op


def delete_run(run_id: int) -> Callable[[Connection], int]:
    def op(conn: Connection) -> int:
        conn.execute(delete(MarkerRow).where(MarkerRow.run_id == run_id))
        return int(conn.execute(delete(RunRow).where(RunRow.id == run_id)).rowcount or 0)

    return op


# --- reads ------------------------------------------------------------------------------------------------


def get_run(engine: Engine, run_id: int) -> dict[str, Any] | None:
    with engine.connect() as conn:
        row = conn.execute(select(RunRow.__table__).where(RunRow.id == run_id)).first()
    return dict(row._mapping) if row is not None else None


def open_runs(engine: Engine) -> list[dict[str, Any]]:
    with engine.connect() as conn:
        rows = conn.execute(select(RunRow.__table__).where(RunRow.ended_at.is_(None))).all()
    return [dict(r._mapping) for r in rows]


def _like(value: str) -> str:
    return value.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")


def list_runs(
    engine: Engine,
    *,
    name: str | None,
    tag: str | None,
    robot: str | None,
    running: bool | None,
    before_id: int | None,
    limit: int,
) -> list[dict[str, Any]]:
    """Newest first; ``name`` matches a part of the name, case-insensitively."""
    stmt = select(RunRow.__table__).order_by(RunRow.id.desc()).limit(limit)
    if name:
        stmt = stmt.where(RunRow.name.ilike(f"%{_like(name)}%", escape="\\"))
    if tag:
        stmt = stmt.where(RunRow.tag_index.like(f"%|{_like(tag)}|%", escape="\\"))
    if robot:
        stmt = stmt.where(RunRow.robot_index.like(f"%|{_like(robot)}|%", escape="\\"))
    if running is not None:
        stmt = stmt.where(RunRow.ended_at.is_(None) if running else RunRow.ended_at.is_not(None))
    if before_id is not None:
        stmt = stmt.where(RunRow.id < before_id)
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(stmt)]


def list_markers(engine: Engine, run_id: int) -> list[dict[str, Any]]:
    stmt = select(MarkerRow.__table__).where(MarkerRow.run_id == run_id).order_by(MarkerRow.ts, MarkerRow.id)
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(stmt)]


def _in_robots(sql: str) -> Any:
    return text(sql).bindparams(bindparam("robots", expanding=True))


def stream_counts(conn: Connection, robots: list[str], start: float, end: float) -> list[dict[str, Any]]:
    if not robots:
        return []
    q = _in_robots(
        "SELECT robot_id, stream, COUNT(*) AS n, MIN(ts) AS first_ts, MAX(ts) AS last_ts FROM telemetry "
        "WHERE robot_id IN :robots AND ts >= :a AND ts <= :b GROUP BY robot_id, stream ORDER BY robot_id, stream"
    )
    rows = conn.execute(q, {"robots": robots, "a": start, "b": end})
    return [
        {"robot_id": r.robot_id, "stream": r.stream, "count": int(r.n), "first_ts": r.first_ts, "last_ts": r.last_ts}
        for r in rows
    ]


def distance(conn: Connection, robot_id: str, start: float, end: float) -> float:
    """Length of the stored trajectory (position x, y), measured piece by piece so memory stays bounded."""
    q = text(
        "SELECT x, y FROM telemetry WHERE robot_id = :r AND stream = 'position' AND ts >= :a AND ts <= :b "
        "AND x IS NOT NULL AND y IS NOT NULL ORDER BY ts, seq"
    )
    total = 0.0
    piece: list[tuple[float, float]] = []
    result = conn.execution_options(stream_results=True, yield_per=DISTANCE_CHUNK).execute(
        q, {"r": robot_id, "a": start, "b": end}
    )
    for x, y in result:
        piece.append((x, y))
        if len(piece) >= DISTANCE_CHUNK:
            total += LineString(piece).length
            piece = piece[-1:]  # the next piece starts where this one ended
    if len(piece) >= 2:
        total += LineString(piece).length
    return total


def command_counts(conn: Connection, robots: list[str], start: float, end: float) -> dict[str, int]:
    if not robots:
        return {}
    q = _in_robots(
        "SELECT status, COUNT(*) AS n FROM commands WHERE robot_id IN :robots AND ts >= :a AND ts <= :b GROUP BY status"
    )
    return {r.status: int(r.n) for r in conn.execute(q, {"robots": robots, "a": start, "b": end})}


def estop_count(conn: Connection, start: float, end: float) -> int:
    q = text("SELECT COUNT(*) FROM events WHERE kind = 'estop' AND ts >= :a AND ts <= :b")
    return int(conn.execute(q, {"a": start, "b": end}).scalar_one())


def alarm_counts(conn: Connection, robots: list[str], start: float, end: float) -> dict[str, int]:
    """Alarms raised during the run on its robots, and fleet-wide ones (robot_key "")."""
    q = _in_robots(
        "SELECT kind, COUNT(*) AS n FROM alarms WHERE robot_key IN :robots AND raised_at >= :a AND raised_at <= :b "
        "GROUP BY kind"
    )
    return {r.kind: int(r.n) for r in conn.execute(q, {"robots": [*robots, ""], "a": start, "b": end})}


def seq_gaps(conn: Connection, robots: list[str], start: float, end: float) -> tuple[list[dict[str, Any]], int, bool]:
    """Seq numbers missing between consecutive stored messages of a stream (in time order; a restart's seq
    that starts again at 0 is not a gap). Returns (the first gaps, missing in all, more than listed)."""
    if not robots:
        return [], 0, False
    q = _in_robots(
        "SELECT robot_id, stream, prev_seq, seq, ts FROM ("
        " SELECT robot_id, stream, seq, ts,"
        "  LAG(seq) OVER (PARTITION BY robot_id, stream ORDER BY ts, seq) AS prev_seq"
        " FROM telemetry WHERE robot_id IN :robots AND ts >= :a AND ts <= :b"
        ") AS t WHERE seq > prev_seq + 1 ORDER BY ts"
    )
    gaps: list[dict[str, Any]] = []
    missing = 0
    for r in conn.execute(q, {"robots": robots, "a": start, "b": end}):
        missing += int(r.seq - r.prev_seq - 1)
        if len(gaps) < MAX_GAPS_LISTED:
            gaps.append(
                {
                    "robot_id": r.robot_id,
                    "stream": r.stream,
                    "lo": int(r.prev_seq) + 1,
                    "hi": int(r.seq) - 1,
                    "ts": r.ts,
                }
            )
    return gaps, missing, missing > sum(g["hi"] - g["lo"] + 1 for g in gaps)


def summary(engine: Engine, run: dict[str, Any], now: float) -> dict[str, Any]:
    robots: list[str] = list(run["robots"])
    start = float(run["started_at"])
    end = float(run["ended_at"]) if run["ended_at"] is not None else now
    with engine.connect() as conn:
        counts = stream_counts(conn, robots, start, end)
        commands = command_counts(conn, robots, start, end)
        alarms = alarm_counts(conn, robots, start, end)
        gaps, missing, truncated = seq_gaps(conn, robots, start, end)
        return {
            "duration_s": max(0.0, end - start),
            "robots": robots,
            "messages": counts,
            "messages_total": sum(c["count"] for c in counts),
            "distance_m": {r: round(distance(conn, r, start, end), 4) for r in robots},
            "commands": sum(commands.values()),
            "commands_by_status": commands,
            "estops": estop_count(conn, start, end),
            "alarms": sum(alarms.values()),
            "alarm_kinds": alarms,
            "gaps": gaps,
            "gaps_missing": missing,
            "gaps_truncated": truncated,
        }


# --- what exports read (streamed: backend/store/run_reads.py) -------------------------------------------


def last_before(engine: Engine, robots: list[str], stream: str, ts: float) -> Any:
    """The payload of the newest row of ``stream`` of any of the robots at or before ``ts`` (None: none)."""
    if not robots:
        return None
    q = _in_robots(
        "SELECT payload FROM telemetry WHERE robot_id IN :robots AND stream = :s AND ts <= :t ORDER BY ts DESC LIMIT 1"
    )
    with engine.connect() as conn:
        return conn.execute(q, {"robots": robots, "s": stream, "t": ts}).scalar()


def clock_offsets(engine: Engine, robots: list[str], start: float, end: float) -> dict[str, list[tuple[float, float]]]:
    """Each robot's measured clock offset over a stretch: ``robot -> [(robot ts, offset s)]`` in time order,
    from its ``health`` stream's ``clock_offset_ms`` (the server's clock minus the robot's; samples without
    one left out). Each robot's last sample before ``start`` comes first, so the offset is known from the
    stretch's first message on."""
    out: dict[str, list[tuple[float, float]]] = {}

    def add(robot_id: str, ts: float, payload: Any) -> None:
        data = orjson.loads(payload) if isinstance(payload, (str, bytes)) else payload
        offset = data.get("clock_offset_ms") if isinstance(data, dict) else None
        if isinstance(offset, (int, float)) and not isinstance(offset, bool) and math.isfinite(offset):
            out.setdefault(robot_id, []).append((float(ts), float(offset) / 1000.0))

    before = text(
        "SELECT ts, payload FROM telemetry WHERE robot_id = :r AND stream = 'health' AND ts < :a "
        "ORDER BY ts DESC LIMIT 10"
    )
    with engine.connect() as conn:
        for rid in robots:
            for row in conn.execute(before, {"r": rid, "a": start}):  # the newest that carries an offset
                add(rid, row.ts, row.payload)
                if rid in out:
                    break
    for health in iter_telemetry(engine, robots, start, end, stream="health"):
        add(health.robot_id, health.ts, health.payload)
    return out


def detections_of_frame(engine: Engine, robot_id: str, ts: float, frame_seq: int, window_s: float = 2.0) -> Any:
    """The apriltag message of one camera frame (same robot and ``frame_seq``, stamped near the frame), or
    None. Detections come a little after their frame, from the same clock; the window bounds the scan."""
    q = text(
        "SELECT payload FROM telemetry WHERE robot_id = :r AND stream = 'apriltag' AND ts >= :a AND ts <= :b "
        "ORDER BY ts"
    )
    with engine.connect() as conn:
        for (payload,) in conn.execute(q, {"r": robot_id, "a": ts - window_s, "b": ts + window_s}):
            data = orjson.loads(payload) if isinstance(payload, (str, bytes)) else payload
            if isinstance(data, dict) and data.get("frame_seq") == frame_seq:
                return data
    return None


def streams_of(engine: Engine, robots: list[str], start: float, end: float) -> list[str]:
    with engine.connect() as conn:
        return sorted({c["stream"] for c in stream_counts(conn, robots, start, end)})
