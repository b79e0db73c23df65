"""Issue 32's acceptance with real parts: Mosquitto, the server, three simulated agents with every disturbance
on. A small sweep is rehearsed (from Python and from the shell), then run for real: the prediction's duration
is within 15 % of the real run's and its coverage within 0.03 of the server's figure; the same seed gives the
same prediction; the server answers its health while a rehearsal runs (it runs in a process of its own).
The whole pool's sweep against its rehearsal is bench/bench_rehearsal.py."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from fleet_client import FleetClient
from tests.support.missions import publish_site, wait_ready
from tests.support.mqtt import MqttProbe
from tests.support.procs import REPO_ROOT, AgentProcess, ServerProcess, base_env

Spawn = Callable[..., AgentProcess]
AREA = [[-0.9, -0.75], [0.9, -0.75], [0.9, 0.45], [-0.9, 0.45]]
WIDTH = 0.3
SEED = 7


def _health_while(server: ServerProcess, stop: threading.Event, answers: list[tuple[float, float, int]]) -> None:
    """GET /api/health every 50 ms until ``stop``: (sent, answered, status) of each."""
    with server.client() as c:
        while not stop.is_set():
            sent = time.time()
            status = c.get("/api/health").status_code
            answers.append((sent, time.time(), status))
            stop.wait(0.05)


def _cli(server: ServerProcess, *args: str) -> subprocess.CompletedProcess[str]:
    env = base_env(FLEET_URL=server.base_url, FLEET_TOKEN=server.token or "")
    cmd = [sys.executable, "-m", "fleet_client.cli", "mission", *args]
    return subprocess.run(cmd, env=env, cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)


@pytest.mark.slow
def test_a_rehearsal_predicts_the_real_run(
    server: ServerProcess, spawn_agent: Spawn, mqtt_probe: Callable[..., MqttProbe], tmp_path: Path
) -> None:
    publish_site(mqtt_probe())
    robots = ["h1", "h2", "h3"]
    for rid, x in zip(robots, (-0.8, -0.2, 0.4), strict=True):
        spawn_agent(rid, "--disturbances", f"--start-pose={x},-0.6,1.57")
    with server.client() as c:
        wait_ready(c, robots)
    with FleetClient(server.base_url, token=server.token) as fleet:
        mid = fleet.create_mission(robots, area=AREA, sweep_width_m=WIDTH, name="rehearsed sweep")["id"]
        stop, answers = threading.Event(), []
        poller = threading.Thread(target=_health_while, args=(server, stop, answers))
        poller.start()
        asked = time.time()
        first = fleet.rehearse_mission(mid, seed=SEED)
        answered = time.time()
        stop.set()
        poller.join()
        # from the shell: the same seed from the same start (the robots drifted since), the same prediction
        tracks_file = tmp_path / "tracks.geojson"
        r = _cli(server, "rehearse", mid, "--seed", str(SEED), "--again", "--tracks", str(tracks_file))
        assert r.returncode == 0, r.stderr
        again = json.loads(r.stdout)
        predicted = first["predicted"]
        tracks = predicted.pop("tracks")
        assert again["predicted"] == predicted and again["start"] == first["start"]
        assert json.loads(tracks_file.read_text()) == tracks
        assert fleet.mission(mid)["rehearsal"]["seed"] == SEED  # kept with the mission

        fleet.start_mission(mid)
        done = fleet.wait_mission(mid, timeout=150)
        run = fleet._request("GET", f"/api/runs/{done['run_id']}").json()

    during = [a for a in answers if asked < a[0] and a[1] < answered]
    slowest = max((a[1] - a[0] for a in during), default=None)
    print(
        f"rehearsal: predicted {predicted['duration_s']} s, covered {predicted['covered_fraction']}, closest "
        f"{predicted['min_separation_m']} m, took {first['took_s']} s (x{first['speed_factor']}); real: "
        f"{done['elapsed_s']} s, covered {done['covered_fraction']}; health answered {len(during)} times during "
        f"it, slowest {slowest}"
    )
    assert predicted["outcome"] == "completed", predicted
    assert len(tracks["features"]) == 3
    assert predicted["collisions"] == 0 and predicted["fence_violations"] == 0
    # the server was not blocked: it answered its health while the rehearsal ran
    assert during and all(a[2] == 200 for a in during), answers
    assert abs(predicted["duration_s"] - done["elapsed_s"]) <= 0.15 * done["elapsed_s"], (predicted, done["elapsed_s"])
    assert abs(predicted["covered_fraction"] - done["covered_fraction"]) <= 0.03, (predicted, done["covered_fraction"])
    assert f"rehearsed with seed {SEED}" in run["notes"], run["notes"]
