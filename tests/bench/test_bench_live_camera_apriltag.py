"""The live, camera and AprilTag benchmarks run end to end on a small setting (numbers are not checked
here: they belong in docs/performance.md; this only proves the harness works)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.bench.helpers import run_all_quick


@pytest.mark.slow
def test_run_all_quick_runs_live_camera_and_apriltag(tmp_path: Path) -> None:
    results = run_all_quick(tmp_path, "live", "camera", "apriltag", timeout=240)
    live, camera, tags = results["live"], results["camera"], results["apriltag"]
    assert live["status"] == camera["status"] == tags["status"] == "ok"
    assert live["ws_messages"] > 0 and live["server_rss_mb"] > 0
    # both REST clients (the lean one and httpx) got commands acked done, and their timings are real
    assert live["cmd_commands"] > 0 and live["cmd_httpx_commands"] > 0
    assert 0 < live["cmd_p50_ms"] < 2000 and 0 < live["cmd_httpx_p50_ms"] < 2000
    assert camera["frames_received"] > 0 and camera["age_p95_ms"] > 0
    assert tags["fps_qd2"] > 0 and tags["recall_qd2"] > 0.9
