"""Retention: deleting old telemetry. Raw rows older than ``raw_days`` are deleted once their minute is
rolled up (clean, ``backend/store/rollup.py``); the aggregates under them are marked ``sealed`` and stand
in for them from then on. Aggregates older than ``agg_days`` are pruned. The audit trail has its own
period (``audit_days``, a year by default): telemetry retention never touches it.

Like the rollup, it works in short transactions (one robot/stream and at most ``chunk_rows`` raw rows each),
each write a turn on ``write_turn``, and one replica at a time on PostgreSQL (``ReplicaLock``).
"""

from __future__ import annotations

from sqlalchemy import Connection, Engine, text

from backend.models import RESOLUTIONS
from backend.store.db import write_turn
from backend.store.minutes import minute_of, minute_sql
from backend.store.rollup import MAX_PASSES, ReplicaLock, RollupReport, pairs_of, roll_dirty


def not_in_run(minute: str) -> str:
    """SQL: the minute starting at ``minute`` overlaps no experiment run of ``:robot_id`` (runs are kept
    until deleted, whatever the raw retention; docs/runs.md). A LIKE's ``_`` in a robot id may spare a
    few more minutes, never fewer."""
    return (
        "NOT EXISTS (SELECT 1 FROM runs r WHERE r.robot_index LIKE '%|' || :robot_id || '|%' "
        f"AND r.started_at < {minute} + 60 AND (r.ended_at IS NULL OR r.ended_at >= {minute}))"
    )


def seal_pair(conn: Connection, robot_id: str, stream: str, cutoff: float, chunk_rows: int) -> int:
    """Delete one pair's raw rows older than ``cutoff`` (whole, clean minutes, none of an experiment run),
    sealing the aggregates under them. Minutes still dirty are left for the rollup. Returns the raw rows
    deleted."""
    dialect = conn.dialect.name
    minute = minute_sql(dialect, "telemetry.ts")
    not_dirty = (
        "NOT EXISTS (SELECT 1 FROM telemetry_dirty d WHERE d.robot_id = telemetry.robot_id "
        f"AND d.stream = telemetry.stream AND d.minute_ts = {minute}) AND {not_in_run(minute)}"
    )
    key = {"robot_id": robot_id, "stream": stream}
    deleted = 0
    lo_bound = 0.0  # epoch seconds: every row is above
    while True:
        with conn.begin():
            lo_ts = conn.execute(
                text(
                    "SELECT min(ts) FROM telemetry WHERE robot_id = :robot_id AND stream = :stream "
                    "AND ts < :c AND ts >= :b"
                ),
                {**key, "c": cutoff, "b": lo_bound},
            ).scalar()
            if lo_ts is None:
                return deleted
            lo = minute_of(float(lo_ts))
            nth = conn.execute(
                text(
                    "SELECT ts FROM telemetry WHERE robot_id = :robot_id AND stream = :stream AND ts >= :lo "
                    "AND ts < :c ORDER BY ts LIMIT 1 OFFSET :n"
                ),
                {**key, "lo": lo, "c": cutoff, "n": chunk_rows},
            ).scalar()
        hi = min(cutoff, cutoff if nth is None else max(minute_of(float(nth)), lo + 60.0))
        params = {**key, "lo": lo, "hi": hi}
        with write_turn(conn, yield_after=True), conn.begin():
            for res in RESOLUTIONS:
                conn.execute(
                    text(
                        f"UPDATE telemetry_{res} SET sealed = true WHERE robot_id = :robot_id AND stream = :stream "
                        f"AND bucket_ts >= :lo AND bucket_ts < :hi AND NOT sealed AND NOT EXISTS ("
                        f"SELECT 1 FROM telemetry_dirty d WHERE d.robot_id = :robot_id AND d.stream = :stream "
                        f"AND d.minute_ts = {minute_sql(dialect, f'telemetry_{res}.bucket_ts')}) "
                        f"AND {not_in_run(minute_sql(dialect, f'telemetry_{res}.bucket_ts'))}"
                    ),
                    params,
                )
            n = conn.execute(
                text(
                    "DELETE FROM telemetry WHERE robot_id = :robot_id AND stream = :stream AND ts >= :lo "
                    f"AND ts < :hi AND {not_dirty}"
                ),
                params,
            ).rowcount
        deleted += max(0, n or 0)
        lo_bound = hi  # dirty minutes below stay (the rollup seals them on a later pass)


def prune_aggregates(conn: Connection, cutoff: float) -> int:
    deleted = 0
    for res in RESOLUTIONS:
        table = f"telemetry_{res}"
        with conn.begin():
            pairs = pairs_of(conn, table)
        for robot_id, stream in pairs:
            with write_turn(conn, yield_after=True), conn.begin():
                n = conn.execute(
                    text(f"DELETE FROM {table} WHERE robot_id = :r AND stream = :s AND bucket_ts < :c"),
                    {"r": robot_id, "s": stream, "c": cutoff},
                ).rowcount
            deleted += max(0, n or 0)
    return deleted


def prune_audit(conn: Connection, cutoff: float, chunk_rows: int) -> int:
    """Delete audit entries older than ``cutoff``, oldest first, ``chunk_rows`` per transaction."""
    deleted = 0
    while True:
        with write_turn(conn, yield_after=True), conn.begin():
            n = conn.execute(
                text("DELETE FROM audit WHERE id IN (SELECT id FROM audit WHERE ts < :c ORDER BY ts, id LIMIT :n)"),
                {"c": cutoff, "n": chunk_rows},
            ).rowcount
        deleted += max(0, n or 0)
        if not n or n < chunk_rows:
            return deleted


def run_retention(
    engine: Engine,
    now: float,
    raw_days: float,
    agg_days: float,
    chunk_rows: int = 20_000,
    audit_days: float = 0.0,
) -> RollupReport:
    """One pass: roll up what is old enough, delete raw rows older than ``raw_days`` (0: keep forever),
    prune aggregates older than ``agg_days`` and audit entries older than ``audit_days`` (0: keep forever)."""
    report = RollupReport()
    with engine.connect() as conn, ReplicaLock(conn) as ok:
        if not ok:
            report.skipped_locked = True
            return report
        if raw_days > 0:
            cutoff = minute_of(now - raw_days * 86400.0)
            for _ in range(MAX_PASSES):  # minutes about to lose their raw rows are rolled up first
                before = report.minutes_rolled
                roll_dirty(conn, cutoff, report)
                if report.minutes_rolled == before:
                    break
            with conn.begin():
                report.pairs = pairs_of(conn, "telemetry")
            for robot_id, stream in report.pairs:
                report.raw_rows_deleted += seal_pair(conn, robot_id, stream, cutoff, chunk_rows)
        if agg_days > 0:
            report.agg_rows_deleted = prune_aggregates(conn, now - agg_days * 86400.0)
        if audit_days > 0:
            report.audit_rows_deleted = prune_audit(conn, now - audit_days * 86400.0, chunk_rows)
    return report
