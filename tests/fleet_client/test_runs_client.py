"""Runs from ``fleet_client`` and the ``fleet-client`` CLI against a real server, broker and agent."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

from fleet_client import FleetClient, FleetError
from tests.support.procs import REPO_ROOT, base_env
from tests.support.runs import raw_rows, wait_online, wait_stored_past


def _cli(server, *args: str) -> subprocess.CompletedProcess[str]:
    env = base_env(FLEET_URL=server.base_url, FLEET_TOKEN=server.token)
    return subprocess.run(
        [sys.executable, "-m", "fleet_client.cli", *args],
        env=env,
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_client_runs_marks_and_opens_a_run_in_pandas(server, spawn_agent, tmp_path: Path):
    spawn_agent("cl-a")
    with server.client() as c:
        wait_online(c, ["cl-a"])
    with FleetClient(server.base_url, server.token) as fleet:
        run = fleet.run_start("client trial", tags=["py"])
        assert run["robots"] == ["cl-a"] and run["running"]
        time.sleep(1.0)
        mk = fleet.marker(run["id"], "from python", robot_id="cl-a")
        assert mk["text"] == "from python"
        with pytest.raises(FleetError) as err:
            fleet.marker(run["id"], "too early", ts=run["started_at"] - 5)
        assert err.value.status_code == 409
        time.sleep(1.0)
        done = fleet.run_stop()  # the one run recording
        assert done["id"] == run["id"] and not done["running"]
        with pytest.raises(FleetError) as err:
            fleet.run_stop()  # none is recording now
        assert err.value.status_code == 409
        assert [r["id"] for r in fleet.runs(tag="py")] == [run["id"]]

        with server.client() as c:
            wait_stored_past(c, ["cl-a"], done["ended_at"])  # the frame and the rows read the same
            frame = fleet.run_frame(run["id"], "position")
            rows = raw_rows(c, "cl-a", "position", done["started_at"], done["ended_at"])
        assert len(frame) == len(rows) > 10
        assert list(frame["seq"]) == [r["seq"] for r in rows]
        assert frame["x"].tolist() == pytest.approx([r["data"]["x"] for r in rows])
        with pytest.raises(FleetError):
            fleet.run_frame(run["id"], "no-such-stream")

        headers = fleet.download_run(run["id"], tmp_path / "run.zip")
        assert headers["x-fleet-run-running"] == "false"
        with zipfile.ZipFile(tmp_path / "run.zip") as zf:
            assert json.loads(zf.read("run.json"))["markers"][0]["text"] == "from python"


def test_cli_run_start_marker_stop(server, spawn_agent, tmp_path: Path):
    spawn_agent("cli-a")
    with server.client() as c:
        wait_online(c, ["cli-a"])
    started = _cli(server, "run", "start", "shell trial", "--robot", "cli-a", "--tag", "sh")
    assert started.returncode == 0, started.stderr
    run = json.loads(started.stdout)
    assert run["name"] == "shell trial" and run["tags"] == ["sh"]
    time.sleep(0.5)
    marked = _cli(server, "marker", "pump on", "--robot", "cli-a")
    assert marked.returncode == 0, marked.stderr
    assert json.loads(marked.stdout)["run_id"] == run["id"]
    stopped = _cli(server, "run", "stop")
    assert stopped.returncode == 0, stopped.stderr
    assert json.loads(stopped.stdout)["running"] is False
    again = _cli(server, "run", "stop", str(run["id"]))
    assert again.returncode == 2 and "already ended" in again.stderr
    shown = json.loads(_cli(server, "run", "show", str(run["id"])).stdout)
    assert [m["text"] for m in shown["markers"]] == ["pump on"] and shown["summary"]["messages_total"] > 0
    listed = _cli(server, "run", "list", "--tag", "sh")
    assert [json.loads(line)["id"] for line in listed.stdout.splitlines()] == [run["id"]]
    out = tmp_path / "run.mcap"
    exported = _cli(server, "run", "export", str(run["id"]), "--format", "mcap", "-o", str(out))
    assert exported.returncode == 0, exported.stderr
    assert out.read_bytes()[:8] == b"\x89MCAP0\r\n"
