"""The live, camera and AprilTag benchmarks run end to end on a small setting (numbers are not checked
here: they belong in docs/performance.md; this only proves the harness works)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_run_all_quick_runs_live_camera_and_apriltag(tmp_path: Path) -> None:
    out = tmp_path / "results.json"
    proc = subprocess.run(
        [sys.executable, "bench/run_all.py", "--quick", "--only", "live", "--only", "camera",
         "--only", "apriltag", "--json", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=240,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = {r["bench"]: r for r in json.loads(out.read_text())}
    live, camera, tags = results["live"], results["camera"], results["apriltag"]
    assert live["status"] == camera["status"] == tags["status"] == "ok"
    assert live["ws_messages"] > 0 and live["commands"] > 0 and live["server_rss_mb"] > 0
    assert camera["frames_received"] > 0 and camera["age_p95_ms"] > 0
    assert tags["fps_qd2"] > 0 and tags["recall_qd2"] > 0.9
