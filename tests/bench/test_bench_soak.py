"""bench/bench_soak.py through ``run_all.py --quick``: two simulated robots for fifteen seconds. Its numbers
are not checked here (the hour's figures are in docs/reliability.md): this proves the harness samples,
queries history, drives the robots, reads the gap counters and the live clients hear the fleet."""

from __future__ import annotations

from pathlib import Path

from tests.bench.helpers import run_all_quick


def test_soak_harness_runs(tmp_path: Path) -> None:
    r = run_all_quick(tmp_path, "soak")["soak"]
    assert r["samples"] >= 10 and r["history_n"] >= 5 and r["history_failures"] == 0
    assert r["always_online"] is True and r["online_at_end"] == 2
    assert r["gaps_open"] == 0 and r["gaps_lost"] == 0
    assert r["ws_received"] > 0 and r["ws_errors"] == 0
    assert r["goto"]["sent"] >= 4 and r["goto"]["answered"] == r["goto"]["sent"]
    assert r["memory"]["min_mb"] > 0 and r["wal_max_mb"] >= 0
