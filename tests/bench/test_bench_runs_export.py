"""The run-export benchmark runs end to end on a small setting (its times belong in docs/performance.md;
this proves it exports what it stored: every row and every frame)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_bench_runs_export_small() -> None:
    proc = subprocess.run(
        [sys.executable, "bench/bench_runs_export.py", "--robots", "2", "--minutes", "0.2", "--frames", "20"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1]
    r = json.loads(line[len("RESULT ") :])
    assert r["rows"] == 2 * 50 * 12 and r["frames"] == 20
    assert r["mcap_messages"] == r["rows"] + r["frames"]
    assert r["mcap_s"] > 0 and r["parquet_s"] > 0
