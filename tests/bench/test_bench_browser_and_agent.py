"""The dashboard, button and agent-memory benchmarks run end to end on a small setting (numbers are not
checked here: they belong in docs/performance.md; this proves each harness works and measures something)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.bench.helpers import run_all_quick

pytestmark = pytest.mark.browser  # the dashboard and button benchmarks drive Chromium: the browser lane


@pytest.mark.slow
def test_run_all_quick_runs_dashboard_button_and_agent_memory(tmp_path: Path) -> None:
    results = run_all_quick(tmp_path, "dashboard", "button", "agent-memory")
    dashboard, button, agent = results["dashboard"], results["button"], results["agent-memory"]
    assert dashboard["status"] == button["status"] == agent["status"] == "ok", results
    assert dashboard["frames"] > 100 and dashboard["map_renders"] > 0 and dashboard["heap_last_mb"] > 0
    # every press reached the agent and was matched to its "accepted" ack
    assert button["presses"] == 5 and button["matched"] == 5 and button["p50_ms"] > 0
    # the camera + AprilTag agent loads the vision stack on top of the basic one
    assert 0 < agent["basic"]["rss_mb"] < agent["camera"]["rss_mb"]
