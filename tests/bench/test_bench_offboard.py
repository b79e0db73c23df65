"""bench/bench_offboard.py runs end to end on a small setting through run_all.py (its figures belong in
docs/performance.md)."""

from __future__ import annotations

from pathlib import Path

from tests.bench.helpers import run_all_quick


def test_bench_offboard_quick(tmp_path: Path) -> None:
    r = run_all_quick(tmp_path, "offboard")["offboard"]
    assert r["status"] == "ok", r
    assert r["robots"] == 2 and r["seconds"] == 3
    # both loops ran at the pose rate (20 Hz, 2 robots, 3 s: ~120 set-points each) and were matched
    assert r["server_setpoints"] > 40 and r["broker_setpoints"] > 40, r
    assert 0 < r["server_p50_ms"] <= r["server_p99_ms"] and 0 < r["broker_p50_ms"] <= r["broker_p99_ms"]
