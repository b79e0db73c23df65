"""bench/bench_mission_limits.py through ``run_all.py --quick``: missions at the edges of their schema posted to a
real server. Its times belong in docs/performance.md; this proves the harness runs and that what it posts is
answered as the limits say (the absurd widths refused by the estimate, the largest plans built)."""

from __future__ import annotations

from pathlib import Path

from tests.bench.helpers import run_all_quick


def test_bench_mission_limits_quick(tmp_path: Path) -> None:
    r = run_all_quick(tmp_path, "mission-limits")["mission-limits"]
    assert r["status"] == "ok" and r["cases"] == 8, r
    answers = r["answers"]
    for case in ("coverage: sweep_width_m 10 um (issue 28)", "coverage: every field at its minimum"):
        assert (answers[case]["status"], answers[case]["code"]) == (422, "too_many_lanes"), answers[case]
    for case in ("coverage: every field at its maximum", "formation: every field at its maximum"):
        assert answers[case]["status"] == 201, answers[case]
    assert answers["waypoints: every field at its maximum"]["status"] == 413  # more than a body may hold
    assert all(a["s"] > 0 for a in answers.values())
    assert r["slowest_s"] == max(a["s"] for a in answers.values())
    assert r["stalls_over_200ms"] >= 0 and r["stalls_over_100ms"] >= r["stalls_over_200ms"]
    assert r["loop_max_lag_ms"] >= r["loop_max_lag_before_ms"] >= 0 and r["health_answers"] > 0
