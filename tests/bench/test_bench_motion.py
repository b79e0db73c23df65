"""bench/bench_motion.py and bench/bench_geofence.py run end to end on small settings (their figures belong
in docs/performance.md)."""

from __future__ import annotations

from tests.bench.helpers import run_bench


def test_bench_motion_small() -> None:
    r = run_bench("bench_motion.py", "--robots", "2", "--goals", "1", "--path-points", "0")
    assert r["bench"] == "motion" and r["goals"] == 2 and r["robots"] == 2
    assert 0 <= r["done_within_5cm_pct"] <= 100 and r["median_time_s"] > 0 and r["goals_wall_s"] > 0


def test_bench_geofence_small() -> None:
    r = run_bench("bench_geofence.py", "--robots", "1", "--attempts", "4")
    assert r["bench"] == "geofence" and r["attempts"] == 4 and r["driven"] == 2 and r["wall_s"] > 0
