"""Runs are kept until deleted: the raw-telemetry retention spares the minutes of an experiment run of a
robot (raw rows stay, their aggregates stay unsealed), and deletes them once the run is deleted."""

from __future__ import annotations

import math
import random
import time

from sqlalchemy import text

from backend.store import runs as run_store
from backend.store.retention import run_retention
from tests.backend.store.test_retention import DAY, _insert, _positions


def _run(engine, robots: list[str], start: float, end: float) -> int:
    values = {
        "name": "kept",
        "notes": "",
        "tags": [],
        "tag_index": "|",
        "operator": "test",
        "robots": robots,
        "robot_index": run_store.index_of(robots),
        "started_at": start,
        "ended_at": end,
        "site_version": 1,
        "agents": {},
        "frame_rate": 5.0,
        "frames": 0,
        "frame_bytes": 0,
        "frames_stopped": False,
        "frames_stopped_reason": "",
    }
    with engine.begin() as conn:
        return run_store.insert_run(values)(conn)


def test_retention_spares_the_minutes_of_a_run(engine):
    rng = random.Random(5)
    now = time.time()
    t0 = math.floor((now - 40 * DAY) / 60) * 60 + 3.1
    old = _positions(t0, 6000, rng)  # r1: 300 s at 20 Hz, 40 days ago (minutes 0..5)
    other = _positions(t0, 6000, rng, robot="r2")
    _insert(engine, old + other)
    start, end = t0 + 125.0, t0 + 170.0  # within minute 2
    run_id = _run(engine, ["r1"], start, end)
    _run(engine, ["r3"], t0, t0 + 400)  # another robot's run spares nothing of r1 or r2

    def in_run(ts: float) -> bool:
        m = math.floor(ts / 60) * 60
        return start < m + 60 and end >= m

    kept = [r for r in old if in_run(r["ts"])]
    assert 0 < len(kept) < len(old)
    report = run_retention(engine, now, 30, 365, chunk_rows=1000)
    assert report.raw_rows_deleted == len(old) - len(kept) + len(other)
    with engine.connect() as conn:
        left = [tuple(r) for r in conn.execute(text("SELECT robot_id, seq FROM telemetry ORDER BY seq"))]
        assert left == [("r1", r["seq"]) for r in kept]
        unsealed = conn.execute(
            text("SELECT count(*) FROM telemetry_1m WHERE robot_id = 'r1' AND NOT sealed")
        ).scalar_one()
        assert unsealed == len({math.floor(r["ts"] / 60) for r in kept})

    # deleting the run lets the retention take its rows on the next pass
    with engine.begin() as conn:
        run_store.delete_run(run_id)(conn)
    again = run_retention(engine, now, 30, 365, chunk_rows=1000)
    assert again.raw_rows_deleted == len(kept)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM telemetry")).scalar_one() == 0
