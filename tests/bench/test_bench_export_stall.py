"""The export-stall benchmark runs end to end on its quick setting (its figures belong in
docs/performance.md): unread exports stay open, every live message is stored, health never fails."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_bench_export_stall_quick() -> None:
    argv = [sys.executable, "bench/bench_export_stall.py", "--quick"]
    proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    r = json.loads([line for line in proc.stdout.splitlines() if line.startswith("RESULT ")][-1][len("RESULT ") :])
    assert r["admitted"] == r["exports"] == 12 and r["open_at_end"] == 12
    for phase in ("quiet", "stalled"):
        assert r[phase]["stored"] == r[phase]["sent"] > 0 and r[phase]["health_failures"] == 0
        assert r[phase]["health_samples"] > 0 and r[phase]["health_max_ms"] > 0
