"""bench/bench_rehearsal.py runs end to end on its small setting through run_all.py: the twin alone, once
(its figures, and the prediction against a real run, belong in docs/performance.md)."""

from __future__ import annotations

from pathlib import Path

from tests.bench.helpers import run_all_quick


def test_bench_rehearsal_quick(tmp_path: Path) -> None:
    r = run_all_quick(tmp_path, "rehearsal")["rehearsal"]
    assert r["status"] == "ok", r
    (run,) = r["twin"]
    assert run["outcome"] == "completed" and run["simulated_s"] > 60 and run["wall_s"] > 0, r
    assert r["speed_factor"] == run["simulated_s"] / run["wall_s"] and "real" not in r, r
