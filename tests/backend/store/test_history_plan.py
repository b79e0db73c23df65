"""History reads positions from the covering index alone (issue 28, the soak's slow history).

The soak's history page asks for ten robots' positions over five minutes in 0.3 s buckets: a GROUP BY over
raw rows per robot. Through an index of (robot_id, stream, ts) SQLite fetched every row's x, y, z from the
table, row by row (0.22 s of CPU for the ten series, growing with the table); migration 0015's
(robot_id, stream, ts, x, y, z) answers from the index. SQLite's plan says which it used.
"""

from __future__ import annotations

import time
from typing import Any

import pytest
from sqlalchemy import Engine, event

from backend.services.telemetry.ingest import telemetry_row
from backend.store.telemetry_inserts import dirty_marks, minutes_of, telemetry_insert
from backend.store.telemetry_query import query_series


def _insert(engine: Engine, rows: list[dict[str, Any]]) -> None:
    with engine.begin() as conn:
        conn.execute(telemetry_insert(engine), rows)
        conn.execute(dirty_marks(engine), minutes_of(rows))


def _group_by_plans(engine: Engine, call: Any) -> list[str]:
    """Run ``call`` and return SQLite's query plan for each GROUP BY over telemetry it sent."""
    sent: list[tuple[str, Any]] = []

    def capture(conn: Any, cursor: Any, statement: str, parameters: Any, context: Any, many: bool) -> None:
        if "GROUP BY" in statement and "FROM telemetry " in statement:
            sent.append((statement, parameters))

    event.listen(engine, "before_cursor_execute", capture)
    try:
        call()
    finally:
        event.remove(engine, "before_cursor_execute", capture)
    raw = engine.raw_connection()
    try:
        cur = raw.cursor()
        plans = []
        for statement, parameters in sent:
            cur.execute("EXPLAIN QUERY PLAN " + statement, parameters)
            plans.append(" | ".join(str(row[-1]) for row in cur.fetchall()))
        return plans
    finally:
        raw.close()


def test_a_bucketed_position_history_reads_the_covering_index(engine, database_url):
    if not database_url.startswith("sqlite"):
        pytest.skip("the plan is SQLite's; PostgreSQL chooses index-only scans by its visibility map")
    now = time.time()
    rows = [
        telemetry_row(robot, "position", now - 300 + i * 0.05, i, {"x": i * 0.01, "y": 1.0, "z": 0.0, "yaw": 0.1})
        for robot in ("r1", "r2", "r3")
        for i in range(6000)
    ]
    _insert(engine, rows)
    # 0.3 s buckets (raw only), then 3 s buckets (raw rows of minutes not rolled up, beside the rollups)
    for max_points in (1000, 100):
        plans = _group_by_plans(engine, lambda n=max_points: query_series(engine, "r2", "position", None, None, n))
        assert plans, f"no GROUP BY over telemetry was sent for {max_points} points"
        for plan in plans:
            assert "COVERING INDEX ix_telemetry_robot_stream_ts_xyz" in plan, plan
    page = query_series(engine, "r2", "position", None, None, 1000)
    assert 900 <= len(page.points) <= 1000
