"""A rehearsal: one mission run in the twin of the fleet, on virtual time, and what it predicts.

The twin is the server's mission service (missions/service.py, the same class the server runs) with the
agent's motion parts on the simulator (robots.py) for each robot, joined by what stands in for the broker
(server.py): the fleet poses of the real pose board and publisher at their rate, with a link's latency and
losses, the server's heartbeat, the commands and their acks. Everything runs on one
:class:`~backend.services.rehearsal.loop.VirtualTimeLoop`: no broker, no sleeping, and the same seed gives the
same run. docs/missions.md, "Rehearsal".
"""

from __future__ import annotations

import asyncio
import math
import random
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from backend.services.fleet.poses import PoseBoard, PosePublisher
from backend.services.missions.record import Mission
from backend.services.missions.service import TICK_S
from backend.services.rehearsal.loop import run_virtual
from backend.services.rehearsal.measure import Measure
from backend.services.rehearsal.robots import TwinClock, TwinRobot, drive
from backend.services.rehearsal.server import (
    TwinBroker,
    TwinCommands,
    TwinHub,
    TwinRegistry,
    TwinSite,
    twin_mission_service,
)
from fleet_protocol import HEARTBEAT_PERIOD_S, SiteMessage, Topics
from robot_agent.sim.world import Pose

SERVER_ID = "rehearsal"
#: the robots hear the site, the heartbeat and the poses for this long before the start (as ready robots have)
WARM_UP_S = 1.0
#: how often the true poses are sampled for the figures (the simulator's truth, not the fixes): robots closing
#: at 0.4 m/s come at most 2 cm nearer between two samples than the closest approach says
SAMPLE_S = 0.1
#: a rehearsal stops after this much simulated time past the plan's estimate, or at ``MAX_SIM_S``
MAX_SIM_S = 3600.0


@dataclass(frozen=True)
class RobotStart:
    """Where a robot is when the rehearsal starts (its latest fix) and what it can do: the agent's published
    ``max_speed_mps``, ``wheel_base_m`` and ``[kinematics]`` (None: the agent's defaults). A robot not in the
    mission (``in_mission`` false) stands where it is, motors off, as a neighbour of the others;
    ``filtered`` false: it runs no safety filter (the old framework), and the others give it all the way."""

    robot_id: str
    x: float
    y: float
    yaw: float
    max_speed_mps: float = 0.3
    wheel_base_m: float = 0.2
    kinematics: dict[str, Any] | None = None
    in_mission: bool = True
    filtered: bool = True


@dataclass(frozen=True)
class RehearsalInput:
    """Everything a rehearsal starts from, as plain data (it crosses into the rehearsal's process)."""

    mission: Mission
    site: dict[str, Any]
    robots: list[RobotStart]
    #: the longest simulated time to run (s)
    limit_s: float = MAX_SIM_S


#: ``tap(robot_id, ts, data)``: each position fix of the twin's robots, as the server would store it
FixTap = Callable[[str, float, dict[str, Any]], None]


def rehearse(inp: RehearsalInput, seed: int, tap: FixTap | None = None) -> dict[str, Any]:
    """Run the mission once in the twin with ``seed``; the prediction (see :class:`Measure`). ``tap`` sees
    every fix (a benchmark measures a formation's slot errors from them as from a real run's stored ones)."""
    started = time.perf_counter()
    predicted = run_virtual(_rehearse(inp, seed, tap))
    took = time.perf_counter() - started
    return {"predicted": predicted, "seed": seed, "took_s": round(took, 3)}


async def _rehearse(inp: RehearsalInput, seed: int, tap: FixTap | None) -> dict[str, Any]:
    loop = asyncio.get_running_loop()
    epoch = time.time()
    clock = TwinClock(loop, epoch)
    rng = random.Random(seed)
    site_msg = SiteMessage.model_validate(inp.site)
    site_payload = site_msg.model_dump_json().encode()
    ids = [r.robot_id for r in inp.robots]
    registry = TwinRegistry(ids)
    board = PoseBoard(registry, clock=loop.time)  # type: ignore[arg-type]

    def on_fix(robot_id: str, ts: float, data: dict[str, Any]) -> None:
        registry.on_fix(robot_id, ts, data)
        board.on_telemetry(robot_id, "position", ts, 0, data)
        if tap is not None:
            tap(robot_id, ts, data)

    robots: dict[str, TwinRobot] = {}
    commands = TwinCommands(robots, clock.now)
    for r in inp.robots:
        robots[r.robot_id] = TwinRobot(
            r.robot_id,
            Pose(r.x, r.y, r.yaw),
            clock=clock,
            seed=seed,
            site_payload=site_payload,
            on_fix=on_fix,
            on_ack=commands.on_ack,
            max_speed_mps=r.max_speed_mps,
            wheel_base_m=r.wheel_base_m,
            kinematics=r.kinematics,
        )
        state = registry.robots[r.robot_id]
        state.collision_filter = state.collision_filter and r.filtered
        state.legacy = not r.filtered
    broker = TwinBroker(robots, loop, rng)
    publisher = PosePublisher(
        board=board, publisher=broker, topics=Topics(), server_id=SERVER_ID, clock=loop.time, wall=clock.now
    )
    hub = TwinHub()
    assert site_msg.site is not None, "a rehearsal needs a site"
    service = twin_mission_service(
        registry=registry,
        commands=commands,
        site=TwinSite(site_msg.site, site_msg.version),
        hub=hub,
        server_id=SERVER_ID,
        clock=clock.now,
    )
    mission = inp.mission
    service.missions[mission.id] = mission
    measure = Measure(site_msg.site, robots, clock, [r.robot_id for r in inp.robots if r.in_mission])

    async def heartbeat() -> None:
        while True:
            for robot in robots.values():
                robot.heard_heartbeat(SERVER_ID)
            await asyncio.sleep(HEARTBEAT_PERIOD_S)

    async def sample() -> None:
        while True:
            measure.sample()
            await asyncio.sleep(SAMPLE_S)

    tasks = [
        loop.create_task(publisher.run()),
        loop.create_task(heartbeat()),
        loop.create_task(drive(list(robots.values()), clock)),
    ]
    try:
        await asyncio.sleep(WARM_UP_S)
        tasks.append(loop.create_task(sample()))
        start = clock.now()
        await service.start_in_twin(mission.id, "rehearsal")
        while mission.state == "running" and clock.now() - start < inp.limit_s:
            await asyncio.sleep(TICK_S)
            await service.step_in_twin(clock.now())
            measure.watch(mission, clock.now())
        end = clock.now()
        measure.watch(mission, end)
        if mission.state == "running":
            await service.end_in_twin(mission.id, f"rehearsal limit of {inp.limit_s:g} s reached")
        measure.sample()
    finally:
        await service.close()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    return measure.prediction(mission, hub.events, start, end)


def speed_factor(predicted: dict[str, Any], took_s: float) -> float:
    """Simulated seconds per wall second."""
    return round(predicted["duration_s"] / took_s, 1) if took_s > 0 else math.inf
