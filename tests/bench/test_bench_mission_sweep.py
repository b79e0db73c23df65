"""bench/bench_mission_sweep.py through ``run_all.py --quick``: two simulated robots sweep a 1 m x 1 m area end to
end (real Mosquitto, server and agents). The figures and their targets belong in docs/performance.md; this
proves the harness runs and measures what it says, from the stored positions."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.bench.helpers import run_all_quick


@pytest.mark.slow
def test_bench_mission_sweep_quick(tmp_path: Path) -> None:
    r = run_all_quick(tmp_path, "mission-sweep", timeout=400)["mission-sweep"]
    assert r["status"] == "ok" and r["robots"] == 2 and r["size_m"] == 1
    assert r["state"] == "completed", r
    assert 0 < r["covered"] <= 1 and r["sweepable_m2"] == 1.0 and r["band_m"] == 0.25
    assert r["run_s"] > 0 and r["ideal_s"] > r["turns_s"] > 0 and r["ratio"] == r["run_s"] / r["ideal_s"]
    assert r["closest_m"] > 0 and r["fence_crossings"] >= 0 and r["work_spread"] >= 0
