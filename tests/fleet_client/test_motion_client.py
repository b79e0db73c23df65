"""goto, follow_path, drive, cancel and the CLI's goto/path/drive/cancel against a real server and a
simulated agent with every disturbance on. Where the robot ended is read from the stored positions."""

from __future__ import annotations

import json
import math
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

import pytest

from fleet_client import CommandFailed, FleetClient, FleetError
from tests.support.procs import REPO_ROOT, base_env


def _position_at(fleet: FleetClient, rid: str, ts: float) -> tuple[float, float]:
    time.sleep(0.8)  # committed
    rows = list(fleet.history_rows(rid, "position", start=ts - 0.15, end=ts + 0.15))
    assert rows, f"no stored fix of {rid} around {ts}"
    return statistics.fmean(r["data"]["x"] for r in rows), statistics.fmean(r["data"]["y"] for r in rows)


def _done_ts(cmd: dict) -> float:
    return next(a["ts"] for a in cmd["acks"] if a["status"] == "done")


#: What ends a goal when the robot's own process is starved of CPU (a machine loaded by other test runs):
#: its ping through the broker unanswered for 0.3 s, its fix late, the server's heartbeat late.
STARVED = frozenset({"link_lost", "no_position", "unsupervised"})


def _reaching(goal: Callable[[], dict], tries: int = 3) -> dict:
    """A goal waited for. One that the robot's supervision ended for one of the STARVED reasons is
    reported as CommandFailed (status ``failed``, that ``failure``) and sent again, up to ``tries`` times."""
    for attempt in range(1, tries + 1):
        try:
            return goal()
        except CommandFailed as exc:
            assert exc.status == "failed" and exc.failure in STARVED, exc
            print(f"attempt {attempt}: {exc}")
            if attempt == tries:
                raise
    raise AssertionError("unreachable")


def test_goto_path_and_cancel(sim_robots, pool_site, fleet):
    sim_robots(("m1", 0.0, 0.0, 0.0))
    cmd = _reaching(lambda: fleet.goto("m1", 0.35, 0.2, tolerance_m=0.05))
    assert cmd["status"] == "done" and cmd["reason"].startswith("reached")
    assert math.dist(_position_at(fleet, "m1", _done_ts(cmd)), (0.35, 0.2)) <= 0.06

    path = [[0.35, 0.5], [0.0, 0.5], [0.0, 0.2]]
    cmd = _reaching(lambda: fleet.follow_path("m1", path, tolerance_m=0.05))
    assert cmd["status"] == "done"
    assert math.dist(_position_at(fleet, "m1", _done_ts(cmd)), (0.0, 0.2)) <= 0.06

    # Outside the fence: refused (by the robot, or by the server with a 422), and nothing moves.
    with pytest.raises(FleetError) as err:
        fleet.goto("m1", 3.0, 0.0)
    assert "geofence" in str(err.value) or err.value.status_code == 422
    if isinstance(err.value, CommandFailed):
        assert err.value.status == "rejected" and err.value.failure == "geofence"

    # A goal cancelled on the way ends "aborted": CommandFailed once waited for.
    sent = fleet.goto("m1", -1.0, -1.0, wait=False)
    assert sent["status"] == "sent"
    time.sleep(1.5)
    assert fleet.command(sent["id"])["status"] == "accepted", "the goal was running when cancelled"
    assert fleet.cancel("m1")["status"] == "done"
    with pytest.raises(CommandFailed) as failed:
        fleet.wait_goal(sent["id"], timeout=10)
    assert failed.value.status == "aborted"

    with pytest.raises(ValueError, match="never ends"):
        fleet.follow_path("m1", path, loop=True)


def _cli(server, *args: str) -> subprocess.CompletedProcess[str]:
    env = base_env(FLEET_URL=server.base_url, FLEET_TOKEN=server.token)
    return subprocess.run(
        [sys.executable, "-m", "fleet_client.cli", *args],
        env=env,
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_cli_goto_path_drive_cancel(server, sim_robots, pool_site):
    sim_robots(("m2", 0.0, 0.0, 0.0))
    r = _cli(server, "goto", "m2", "0.3", "0.0", "--max-speed", "0.2")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["status"] == "done"
    r = _cli(server, "path", "m2", "0.3,0.3", "0,0.3")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["status"] == "done"
    r = _cli(server, "goto", "m2", "5", "5")  # outside the pool
    assert r.returncode in (1, 2) and ("geofence" in r.stdout or "422" in r.stderr), (r.stdout, r.stderr)
    r = _cli(server, "drive", "m2", "0.05", "0.3", "--duration", "0.4")
    assert r.returncode == 0, r.stderr
    drive = json.loads(r.stdout)
    assert drive["command"] == "drive" and drive["status"] == "done"
    r = _cli(server, "cancel", "m2")
    assert r.returncode == 0 and json.loads(r.stdout)["command"] == "stop"
