"""bench/bench_collisions.py and bench/bench_filter_cost.py run end to end on small settings through run_all.py
(their figures belong in docs/performance.md)."""

from __future__ import annotations

from pathlib import Path

from bench.twin_crossing import run_twin_crossing
from tests.bench.helpers import run_all_quick, run_bench


def test_bench_collisions_and_filter_cost_quick(tmp_path: Path) -> None:
    results = run_all_quick(tmp_path, "collisions", "filter-cost")
    r = results["collisions"]
    assert r["status"] == "ok", r
    assert r["robots"] == 2 and r["goals"] >= 2 and r["closest_m"] >= 0.25 and r["other_ends"] == [], r
    cost = results["filter-cost"]
    assert cost["status"] == "ok" and cost["neighbours"] == 20 and cost["ticks"] == 50, cost
    for kind in ("far", "ring", "crowd"):
        assert 0 < cost[kind]["p50_ms"] <= cost[kind]["p99_ms"] <= cost[kind]["max_ms"], cost


def test_bench_collisions_in_the_twin_is_deterministic() -> None:
    """``bench_collisions.py --twin``: six robots on crossing gotos in the rehearsal twin, 20 simulated seconds;
    the same seed gives the same goals, outcomes and distances."""
    result = run_bench("bench_collisions.py", "--twin", "1", "--seconds", "20", timeout=120)
    (run,) = result["runs"]
    assert run["goals"] >= 6 and run["done"] >= 1 and run["closest_m"] >= 0.25, run
    again = run_twin_crossing(6, 20.0, 1000).figures()
    assert {k: v for k, v in again.items() if k != "took_s"} == {k: v for k, v in run.items() if k != "took_s"}
