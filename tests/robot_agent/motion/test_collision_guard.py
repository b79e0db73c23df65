"""Robots never collide (issue 31; docs/safety.md): the safety filter on real simulated robots, every disturbance
on, behind a real server that publishes the fleet's poses. Distances are the run summary's: measured from the
stored positions, the other robot interpolated to each sample's time (backend/services/runs/separation.py).

Bodies are 0.1 m in radius; the site keeps 0.3 m between centres (+ the margins of docs/autonomy.md), and the
promise measured here is at least 0.25 m, whatever the operators, the goals or an off-board controller ask."""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from fleet_client import CommandFailed, FleetClient
from tests.backend.helpers import register_legacy, wait_stored
from tests.support.client_motion import fleet, server, sim_robots
from tests.support.crossing import BLOCKED, ring, run_crossing
from tests.support.procs import ServerProcess
from tests.support.seed_robot import SeedRobot

__all__ = ["fleet", "server", "sim_robots"]

#: the promise: centre to centre, bodies of 0.1 m radius
CLOSEST_M = 0.25
FULL_SPEED = 0.2  # the simulated robots' max_linear_mps


def _run(c: FleetClient, name: str, robots: list[str]) -> str:
    r = c._request("POST", "/api/runs", ok=(201, 200), json={"name": name, "robots": robots})
    return str(r.json()["id"])


def _separation(c: FleetClient, run_id: str) -> dict[str, Any]:
    run = c._request("POST", f"/api/runs/{run_id}/stop").json()
    wait_stored(c._get, run["robots"], run["ended_at"])  # its last positions are in the summary
    return dict(c._get(f"/api/runs/{run_id}")["summary"]["separation"])


def _avoidance(c: FleetClient, robot: str, start: float, end: float) -> list[dict[str, Any]]:
    return [r["data"] for r in c.history_rows(robot, "avoidance", start=start, end=end)]


def _distance(c: FleetClient, a: str, b: str) -> float:
    ra, rb = c.robot(a)["position"], c.robot(b)["position"]
    return math.hypot(ra["x"] - rb["x"], ra["y"] - rb["y"])


async def _drive_both(server: ServerProcess, robots: list[str], plan: list[tuple[float, float]]) -> None:
    """Two operators, two clients, two leases: each holds its robot's drive for each (speed, seconds)."""
    a = FleetClient(server.base_url, token=server.token)
    b = FleetClient(server.base_url, token=server.token)
    try:
        async with (
            a.control(robots[0], client_id="operator-a") as ca,
            b.control(robots[1], client_id="operator-b") as cb,
        ):
            for speed, seconds in plan:
                await ca.drive(speed, 0.0)
                await cb.drive(speed, 0.0)
                await asyncio.sleep(seconds)
            await ca.stop()
            await cb.stop()
    finally:
        a.close()
        b.close()


@pytest.mark.realtime  # its closest approach needs the agents' control on time: a starved CPU breaks it
def test_two_operators_driving_head_on_keep_the_robots_apart_and_away_is_obeyed(
    server: ServerProcess, fleet: FleetClient, sim_robots: Callable[..., list[str]]
) -> None:
    robots = sim_robots(("ho-1", -0.3, 0.0, 0.0), ("ho-2", 0.3, 0.02, math.pi))
    run = _run(fleet, "head-on", robots)
    # 1. Away: 0.6 m apart, facing each other, both back off at full speed: the filter leaves it alone.
    start = time.time()
    before = _distance(fleet, *robots)
    asyncio.run(_drive_both(server, robots, [(-FULL_SPEED, 1.5)]))
    time.sleep(0.5)  # the operators let go for half a second before they drive at each other (the scenario)
    after = _distance(fleet, *robots)
    away = [m for r in robots for m in _avoidance(fleet, r, start, time.time()) if m["event"] == "active"]
    assert away == [], away
    assert after - before > 2 * FULL_SPEED * 1.5 * 0.7, (before, after)  # both moved away near full speed
    # 2. Head-on: 1.2 m apart, both drive at each other at full speed for 8 s (1.6 m each: they would meet).
    asyncio.run(_drive_both(server, robots, [(FULL_SPEED, 8.0)]))
    sep = _separation(fleet, run)
    assert sep["closest"] is not None and sep["closest"]["distance_m"] >= CLOSEST_M, sep
    assert sep["contacts"] == 0, sep
    # the filter did it: both robots were held back, and each robot went past the other (no deadlock)
    assert all(sep["interventions_by_robot"][r]["count"] >= 1 for r in robots), sep
    x1, x2 = fleet.robot(robots[0])["position"]["x"], fleet.robot(robots[1])["position"]["x"]
    assert x1 > x2, (x1, x2)


def test_an_off_board_controller_steering_into_another_robot_is_filtered(
    server: ServerProcess, fleet: FleetClient, sim_robots: Callable[..., list[str]]
) -> None:
    robots = sim_robots(("ob-1", -0.8, 0.0, 0.0), ("ob-2", 0.4, 0.0, math.pi / 2))
    run = _run(fleet, "off-board", robots)

    async def ram() -> None:  # a controller with a bug: steers straight at the other robot for 8 s
        async with fleet.control(robots[0], watch=[robots[1]], client_id="buggy") as ctl:
            deadline = time.monotonic() + 8.0
            while time.monotonic() < deadline:
                me, other = ctl.pose, ctl.pose_of(robots[1])
                if me and other and me.get("yaw") is not None:
                    bearing = math.atan2(other["y"] - me["y"], other["x"] - me["x"])
                    err = math.atan2(math.sin(bearing - me["yaw"]), math.cos(bearing - me["yaw"]))
                    await ctl.drive(FULL_SPEED, max(-1.5, min(1.5, 3.0 * err)))
                await asyncio.sleep(0.05)

    asyncio.run(ram())
    sep = _separation(fleet, run)
    assert sep["closest"]["distance_m"] >= CLOSEST_M, sep
    assert sep["interventions_by_robot"][robots[0]]["count"] >= 1, sep  # held back, not lucky


@pytest.mark.realtime  # its closest approach needs the agents' control on time: a starved CPU breaks it
def test_six_robots_on_crossing_gotos_keep_apart_and_reach_their_goals(
    server: ServerProcess, fleet: FleetClient, sim_robots: Callable[..., list[str]]
) -> None:
    """The suite's 60 s of bench/bench_collisions.py (fixed seed; tests/support/crossing.py)."""
    robots = sim_robots(*ring(6))
    run = _run(fleet, "crossing", robots)
    crossing = run_crossing(fleet, robots, 60.0)
    sep = _separation(fleet, run)
    results = crossing.results
    assert sep["closest"]["distance_m"] >= CLOSEST_M and sep["contacts"] == 0, sep
    # The issue asks 95 % done over 5 minutes: bench/bench_collisions.py measures it (docs/performance.md). A
    # minute holds about twenty goals, too few to tell 95 % from 90 % without failing one run in five: the
    # suite holds the robots to three in four, the benchmark to the figure.
    assert len(results) >= 12 and crossing.done >= 0.75 * len(results), crossing.outcomes
    # every goal ended: done, failed: blocked once held back 10 s without progress, or failed (or, sent during
    # one, refused) for no_position in one of the simulator's Lighthouse dropouts; never a stall, a timeout or
    # silence (none was blocked for 20 s). The refused ones still count against the done share above.
    ended = ("done", BLOCKED, "failed: no_position", "rejected: no_position")
    assert [o for o in results if not o.startswith(ended)] == [], crossing.outcomes
    assert sep["interventions"] >= 1, sep  # they did meet on the way


def test_a_new_robot_gives_way_to_an_old_framework_robot_driven_into_it(
    server: ServerProcess,
    fleet: FleetClient,
    sim_robots: Callable[..., list[str]],
) -> None:
    """The old robot has no filter: it drives on (at 0.1 m/s, straight down the new one's way) and the new one,
    on a goto towards it, takes the whole of the avoidance (docs/safety.md says what it cannot do: a stopped
    robot is never moved, and a faster old robot can still run into a new one)."""
    with server.client() as c:
        register_legacy(c, "old-1")
    seed = SeedRobot(server.broker.host, server.broker.port, "old-1")
    stop = threading.Event()

    def drive_old_robot() -> None:  # the seed's robot as its operator drives it: a fix every 0.1 s
        x = 0.9
        while not stop.is_set() and x > -0.9:
            seed.publish_position(x, 0.03)
            x -= 0.01
            time.sleep(0.1)

    try:
        seed.publish_position(0.9, 0.03)
        (robot,) = sim_robots(("nw-1", -0.9, 0.0, 0.0))
        run = _run(fleet, "old and new", [robot, "old-1"])
        old = threading.Thread(target=drive_old_robot)
        old.start()
        try:
            fleet.goto(robot, 1.3, 0.0, timeout_s=40.0, wait_timeout=45.0)  # beyond the old robot
            outcome = "done"
        except CommandFailed as exc:
            outcome = f"{exc.command.get('status')}: {exc.command.get('reason', '')}"
        stop.set()
        old.join(5)
        sep = _separation(fleet, run)
    finally:
        stop.set()
        seed.close()
    assert sep["closest"]["distance_m"] >= CLOSEST_M, sep
    assert sep["interventions_by_robot"][robot]["count"] >= 1, sep  # it did give way
    assert outcome == "done" or outcome.startswith("failed: blocked"), outcome
