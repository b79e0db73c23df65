"""Rollups: raw telemetry folded into exact per-second and per-minute aggregates.

Each minute whose raw rows changed is marked in ``telemetry_dirty`` by the writer (same transaction as the
rows). Every few seconds the rollup recomputes the per-second and per-minute aggregates of dirty minutes
from the raw rows (replace), then clears the mark - only if its ``version`` did not move meanwhile, so
rows committed during the rollup leave the minute dirty for the next pass. Long-range history queries
then read a few aggregate rows instead of millions of raw rows. Rows arriving for a minute retention has
sealed (``backend/store/retention.py``; a very late robot) are merged into the sealed aggregates (counts
and sums add, min/max combine, the last row wins) and deleted.

All of it runs in short transactions (one robot/stream, at most ``MAX_MINUTES_PER_CHUNK`` minutes each),
each write taken as a turn on ``write_turn`` (SQLite: the ingest thread queues on a lock, not in SQLite's
polling busy handler, and the job steps aside after each turn), so the ingest thread never waits long.
On PostgreSQL a session advisory lock lets one replica at a time do it (``ReplicaLock``); the merge of
late rows runs in REPEATABLE READ (the rows it aggregates are exactly the rows it deletes).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from sqlalchemy import Connection, Engine, text

from backend.models import RESOLUTIONS
from backend.store.db import write_turn
from backend.store.minutes import minute_sql

#: pg_try_advisory_lock key of the rollup/retention job ("flrt")
ADVISORY_LOCK_KEY = 0x666C_7274
_AXES = ("x", "y", "z")
#: a rollup transaction covers at most this many minutes of one robot/stream
MAX_MINUTES_PER_CHUNK = 10
#: rollup batches per call at most (a backlog is worked off over several calls)
MAX_PASSES = 50


@dataclass
class RollupReport:
    minutes_rolled: int = 0
    chunks: int = 0
    late_rows_merged: int = 0
    raw_rows_deleted: int = 0
    agg_rows_deleted: int = 0
    audit_rows_deleted: int = 0
    skipped_locked: bool = False
    pairs: list[tuple[str, str]] = field(default_factory=list)


def _bucket_expr(dialect: str, width: float) -> str:
    if dialect == "postgresql":
        return f"(floor(ts / {width!r}) * {width!r})"
    return f"(CAST(ts / {width!r} AS INTEGER) * {width!r})"  # ts > 0: truncation is floor


def _least(dialect: str, a: str, b: str) -> str:
    if dialect == "postgresql":
        return f"LEAST({a}, {b})"  # ignores NULLs
    return f"min(coalesce({a}, {b}), coalesce({b}, {a}))"


def _greatest(dialect: str, a: str, b: str) -> str:
    if dialect == "postgresql":
        return f"GREATEST({a}, {b})"
    return f"max(coalesce({a}, {b}), coalesce({b}, {a}))"


def fold_sql(dialect: str, table: str, width: float, extra_where: str = "") -> str:
    """INSERT ... SELECT the buckets of one pair's [lo, hi) raw rows; an existing bucket is merged."""
    bucket = _bucket_expr(dialect, width)
    axis_cols = ", ".join(f"{a}_sum, {a}_min, {a}_max" for a in _AXES)
    axis_aggs = ", ".join(f"sum({a}), min({a}), max({a})" for a in _AXES)
    t, e = table, "excluded"

    def _sum(col: str) -> str:
        a, b = f"{t}.{col}", f"{e}.{col}"
        return f"CASE WHEN {a} IS NULL THEN {b} WHEN {b} IS NULL THEN {a} ELSE {a} + {b} END"

    newer = f"({e}.last_ts > {t}.last_ts OR ({e}.last_ts = {t}.last_ts AND {e}.last_seq >= {t}.last_seq))"
    older = f"({e}.first_ts < {t}.first_ts OR ({e}.first_ts = {t}.first_ts AND {e}.first_seq <= {t}.first_seq))"
    updates = [
        f"n = {t}.n + {e}.n",
        f"ts_sum = {t}.ts_sum + {e}.ts_sum",
        f"first_seq = CASE WHEN {older} THEN {e}.first_seq ELSE {t}.first_seq END",
        f"last_seq = CASE WHEN {newer} THEN {e}.last_seq ELSE {t}.last_seq END",
        f"yaw = CASE WHEN {newer} THEN {e}.yaw ELSE {t}.yaw END",
        f"payload = CASE WHEN {newer} THEN {e}.payload ELSE {t}.payload END",
        f"first_ts = {_least(dialect, f'{t}.first_ts', f'{e}.first_ts')}",
        f"last_ts = {_greatest(dialect, f'{t}.last_ts', f'{e}.last_ts')}",
        f"xyz_n = {t}.xyz_n + {e}.xyz_n",
    ]
    for a in _AXES:
        updates.append(f"{a}_sum = {_sum(f'{a}_sum')}")
        updates.append(f"{a}_min = {_least(dialect, f'{t}.{a}_min', f'{e}.{a}_min')}")
        updates.append(f"{a}_max = {_greatest(dialect, f'{t}.{a}_max', f'{e}.{a}_max')}")
    return f"""
INSERT INTO {table} (robot_id, stream, bucket_ts, n, ts_sum, first_ts, last_ts, first_seq, last_seq,
                     {axis_cols}, xyz_n, yaw, payload)
SELECT :robot_id, :stream, b, count(*), sum(ts), min(ts), max(ts),
       max(CASE WHEN rn_first = 1 THEN seq END), max(CASE WHEN rn_last = 1 THEN seq END),
       {axis_aggs}, count(x),
       max(CASE WHEN rn_last = 1 THEN yaw END), max(CASE WHEN rn_last = 1 THEN payload END)
FROM (
    SELECT ts, seq, x, y, z, yaw, payload, b,
           row_number() OVER (PARTITION BY b ORDER BY ts, seq) AS rn_first,
           row_number() OVER (PARTITION BY b ORDER BY ts DESC, seq DESC) AS rn_last
    FROM (
        SELECT ts, seq, x, y, z, yaw, payload, {bucket} AS b
        FROM telemetry
        WHERE robot_id = :robot_id AND stream = :stream AND ts >= :lo AND ts < :hi{extra_where}
    ) AS src
) AS ranked
WHERE true
GROUP BY b
ON CONFLICT (robot_id, stream, bucket_ts) DO UPDATE SET {", ".join(updates)}
"""


def pairs_of(conn: Connection, table: str) -> list[tuple[str, str]]:
    """Distinct (robot_id, stream) by a loose index scan: one index probe per pair, not a table scan."""
    out: list[tuple[str, str]] = []
    row = conn.execute(text(f"SELECT robot_id, stream FROM {table} ORDER BY robot_id, stream LIMIT 1")).first()
    while row is not None:
        out.append((row[0], row[1]))
        row = conn.execute(
            text(
                # a row value, not "a > :r OR (a = :r AND b > :s)": SQLite would scan the table for the OR
                f"SELECT robot_id, stream FROM {table} WHERE (robot_id, stream) > (:r, :s) "
                "ORDER BY robot_id, stream LIMIT 1"
            ),
            {"r": row[0], "s": row[1]},
        ).first()
    return out


# ---------------------------------------------------------------------------------------------------
# Rollup of dirty minutes
# ---------------------------------------------------------------------------------------------------


def _chunks(marks: list[tuple[str, str, float, int]]) -> list[tuple[str, str, list[tuple[float, int]]]]:
    """Group (robot, stream, minute, version) marks into runs of consecutive minutes of one pair."""
    out: list[tuple[str, str, list[tuple[float, int]]]] = []
    for robot_id, stream, minute, version in marks:
        if out and out[-1][0] == robot_id and out[-1][1] == stream:
            run = out[-1][2]
            if minute == run[-1][0] + 60.0 and len(run) < MAX_MINUTES_PER_CHUNK:
                run.append((minute, version))
                continue
        out.append((robot_id, stream, [(minute, version)]))
    return out


def _clear_marks(conn: Connection, robot_id: str, stream: str, run: list[tuple[float, int]]) -> None:
    """Delete the marks whose version is still the one read: a mark bumped meanwhile stays."""
    conn.execute(
        text("DELETE FROM telemetry_dirty WHERE robot_id = :r AND stream = :s AND minute_ts = :m AND version = :v"),
        [{"r": robot_id, "s": stream, "m": m, "v": v} for m, v in run],
    )


def _sealed_minutes(conn: Connection, robot_id: str, stream: str, lo: float, hi: float) -> set[float]:
    rows = conn.execute(
        text(
            "SELECT bucket_ts FROM telemetry_1m WHERE robot_id = :r AND stream = :s AND bucket_ts >= :lo "
            "AND bucket_ts < :hi AND sealed"
        ),
        {"r": robot_id, "s": stream, "lo": lo, "hi": hi},
    )
    return {float(r[0]) for r in rows}


def _replace(conn: Connection, robot_id: str, stream: str, run: list[tuple[float, int]]) -> None:
    """Recompute the aggregates of unsealed minutes from their raw rows."""
    dialect = conn.dialect.name
    lo, hi = run[0][0], run[-1][0] + 60.0
    params = {"robot_id": robot_id, "stream": stream, "lo": lo, "hi": hi}
    with write_turn(conn, yield_after=True), conn.begin():
        for res, width in RESOLUTIONS.items():
            conn.execute(
                text(
                    f"DELETE FROM telemetry_{res} WHERE robot_id = :robot_id AND stream = :stream "
                    "AND bucket_ts >= :lo AND bucket_ts < :hi AND NOT sealed"
                ),
                params,
            )
            conn.execute(text(fold_sql(dialect, f"telemetry_{res}", width)), params)
        _clear_marks(conn, robot_id, stream, run)


def _merge_late(conn: Connection, robot_id: str, stream: str, minutes: list[tuple[float, int]]) -> int:
    """Rows that arrived for sealed minutes: merge them into the sealed aggregates, delete them."""
    dialect = conn.dialect.name
    merged = 0
    if dialect == "postgresql":
        conn.execution_options(isolation_level="REPEATABLE READ")
    try:
        for minute, version in minutes:
            params = {"robot_id": robot_id, "stream": stream, "lo": minute, "hi": minute + 60.0}
            with write_turn(conn, yield_after=True), conn.begin():
                for res, width in RESOLUTIONS.items():
                    conn.execute(text(fold_sql(dialect, f"telemetry_{res}", width)), params)
                n = conn.execute(
                    text(
                        "DELETE FROM telemetry WHERE robot_id = :robot_id AND stream = :stream "
                        "AND ts >= :lo AND ts < :hi"
                    ),
                    params,
                ).rowcount
                merged += max(0, n or 0)
                _clear_marks(conn, robot_id, stream, [(minute, version)])
    finally:
        if dialect == "postgresql":
            conn.execution_options(isolation_level="READ COMMITTED")
    return merged


def roll_dirty(
    conn: Connection,
    settled_before: float,
    report: RollupReport,
    max_minutes: int = 5000,
    deadline: float = math.inf,
) -> None:
    """Roll up dirty minutes that ended before ``settled_before`` (at most ``max_minutes`` per call, and
    no new chunk after the ``time.monotonic()`` deadline)."""
    with conn.begin():
        marks = [
            (r[0], r[1], float(r[2]), int(r[3]))
            for r in conn.execute(
                text(
                    "SELECT robot_id, stream, minute_ts, version FROM telemetry_dirty WHERE minute_ts <= :s "
                    "ORDER BY robot_id, stream, minute_ts LIMIT :n"
                ),
                {"s": settled_before - 60.0, "n": max_minutes},
            )
        ]
    for robot_id, stream, run in _chunks(marks):
        if time.monotonic() > deadline:
            return
        with conn.begin():
            sealed = _sealed_minutes(conn, robot_id, stream, run[0][0], run[-1][0] + 60.0)
        open_minutes = [mv for mv in run if mv[0] not in sealed]
        # split the open minutes into contiguous runs again (sealed ones may sit in between)
        for _, _, sub in _chunks([(robot_id, stream, m, v) for m, v in open_minutes]):
            _replace(conn, robot_id, stream, sub)
            report.chunks += 1
        late = [mv for mv in run if mv[0] in sealed]
        if late:
            report.late_rows_merged += _merge_late(conn, robot_id, stream, late)
        report.minutes_rolled += len(run)


# ---------------------------------------------------------------------------------------------------
# Entry points (one connection, the advisory lock on PostgreSQL)
# ---------------------------------------------------------------------------------------------------


class ReplicaLock:
    """On PostgreSQL a session advisory lock: one replica at a time rolls up or deletes (elsewhere: always)."""

    def __init__(self, conn: Connection) -> None:
        self.conn = conn
        self.held = False

    def __enter__(self) -> bool:
        if self.conn.dialect.name != "postgresql":
            return True
        with self.conn.begin():
            self.held = bool(
                self.conn.execute(text("SELECT pg_try_advisory_lock(:k)"), {"k": ADVISORY_LOCK_KEY}).scalar()
            )
        return self.held

    def __exit__(self, *exc: object) -> None:
        if self.held:
            with self.conn.begin():
                self.conn.execute(text("SELECT pg_advisory_unlock(:k)"), {"k": ADVISORY_LOCK_KEY})


def run_rollup(
    engine: Engine, now: float, settle_s: float = 2.0, max_minutes: int = 5000, budget_s: float = math.inf
) -> RollupReport:
    """Roll up every dirty minute that ended ``settle_s`` ago (the current minute keeps being raw), or as
    many as ``budget_s`` seconds allow (a backlog is then worked off over several calls)."""
    report = RollupReport()
    deadline = time.monotonic() + budget_s
    with engine.connect() as conn, ReplicaLock(conn) as ok:
        if not ok:
            report.skipped_locked = True
            return report
        for _ in range(MAX_PASSES):
            before = report.minutes_rolled
            roll_dirty(conn, now - settle_s, report, max_minutes, deadline)
            if report.minutes_rolled - before < max_minutes or time.monotonic() > deadline:
                break
    return report


def mark_all_dirty(engine: Engine) -> None:
    """Mark every stored minute dirty (rows written behind the writer's back, e.g. a bulk load)."""
    with write_turn(engine), engine.begin() as conn:
        minute = minute_sql(conn.dialect.name)
        conn.execute(
            text(
                f"INSERT INTO telemetry_dirty (robot_id, stream, minute_ts, version) "
                f"SELECT DISTINCT robot_id, stream, {minute}, 0 FROM telemetry WHERE true "
                "ON CONFLICT (robot_id, stream, minute_ts) DO UPDATE SET version = telemetry_dirty.version + 1"
            )
        )


def dirty_minutes(conn: Connection, robot_id: str, stream: str, lo: float, hi: float) -> list[float]:
    rows = conn.execute(
        text(
            "SELECT minute_ts FROM telemetry_dirty WHERE robot_id = :r AND stream = :s AND minute_ts >= :lo "
            "AND minute_ts < :hi"
        ),
        {"r": robot_id, "s": stream, "lo": lo, "hi": hi},
    )
    return [float(r[0]) for r in rows]
