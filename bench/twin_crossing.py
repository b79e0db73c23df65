"""Robots on random crossing gotos (tests/support/crossing.py's scenario) in the rehearsal twin: the robots'
own command handler, motion runner and safety filter on the simulator with every disturbance on, the fleet
poses as the server publishes them (latency, losses), on a virtual clock. A minute of six robots takes a few
seconds, deterministic for a seed: the way to judge a change of the filter on crossings before a real run
(``bench_collisions.py --twin``), beside ``bench_formation_filter.py --twin`` for formations.

Distances are the simulator's truth (centres, every 50 ms); goals end as the agent acks them."""

from __future__ import annotations

import asyncio
import itertools
import math
import random
import time
from dataclasses import dataclass, field
from typing import Any

from backend.schemas.commands import CommandCreate
from backend.services.fleet.poses import PoseBoard, PosePublisher
from backend.services.rehearsal.loop import run_virtual
from backend.services.rehearsal.robots import TwinClock, TwinRobot, drive
from backend.services.rehearsal.server import TwinBroker, TwinCommands, TwinRegistry
from fleet_protocol import FINAL_ACK_STATUSES, HEARTBEAT_PERIOD_S, AvoidanceSettings, SiteMessage, Topics
from fleet_protocol.motion import default_pool_site
from robot_agent.sim.world import Pose
from tests.support.crossing import BLOCKED, FREE_M, GOAL_SPAN_M, MIN_TRIP_M, Crossing, ring

SERVER_ID = "twin-crossing"
#: the robots hear the poses for this long before the first goal
WARM_UP_S = 1.0
#: how often the closest approach is measured
SAMPLE_S = 0.05
#: a goal's own time limit, as the suite's operators give it
GOAL_TIMEOUT_S = 40.0
#: an operator's time between a goal's end and the next request (a round trip over REST, as in the suite)
OPERATOR_S = 0.1


@dataclass
class TwinCrossing(Crossing):
    """What became of every goal (:class:`~tests.support.crossing.Crossing`), the closest approach and the
    filter's records."""

    seconds: float = 0.0
    closest_m: float = math.inf
    #: when, and each robot's wheel set-points then, as asked and as the filter gave them to the motors (a parked
    #: robot keeping clear asks nothing and is given a move)
    closest_at: dict[str, Any] = field(default_factory=dict)
    under_m: dict[float, float] = field(default_factory=dict)
    interventions: int = 0
    took_s: float = 0.0

    def figures(self) -> dict[str, Any]:
        n = len(self.results)
        return {
            "goals": n,
            "done": self.done,
            "done_fraction": round(self.done / n, 4) if n else None,
            "blocked": self.blocked,
            "other": sorted({o for o in self.results if o != "done" and not o.startswith(BLOCKED)}),
            "closest_m": round(self.closest_m, 4),
            "closest_at": self.closest_at,
            "seconds_under": {f"{k:g}": round(v, 2) for k, v in self.under_m.items()},
            "interventions": self.interventions,
            "took_s": round(self.took_s, 2),
        }


def run_twin_crossing(robots: int, seconds: float, seed: int, avoidance: bool = True) -> TwinCrossing:
    """``robots`` on the ring of the suite's test, each sent on goals for ``seconds`` (simulated)."""
    started = time.perf_counter()
    out = run_virtual(_crossing(robots, seconds, seed, avoidance))
    out.took_s = time.perf_counter() - started
    return out


async def _crossing(n: int, seconds: float, seed: int, avoidance: bool) -> TwinCrossing:
    loop = asyncio.get_running_loop()
    clock = TwinClock(loop, float(int(time.time())))  # whole seconds: the same float arithmetic every run
    rng = random.Random(seed)
    site = SiteMessage(version=1, site=default_pool_site(), avoidance=AvoidanceSettings(enabled=avoidance))
    starts = ring(n)
    ids = [rid for rid, *_ in starts]
    registry = TwinRegistry(ids)
    board = PoseBoard(registry, clock=loop.time)  # type: ignore[arg-type]

    def on_fix(robot_id: str, ts: float, data: dict[str, Any]) -> None:
        registry.on_fix(robot_id, ts, data)
        board.on_telemetry(robot_id, "position", ts, 0, data)

    twins: dict[str, TwinRobot] = {}
    commands = TwinCommands(twins, clock.now)
    payload = site.model_dump_json().encode()
    for rid, x, y, yaw in starts:
        twins[rid] = TwinRobot(
            rid, Pose(x, y, yaw), clock=clock, seed=seed, site_payload=payload, on_fix=on_fix, on_ack=commands.on_ack
        )
    publisher = PosePublisher(
        board=board,
        publisher=TwinBroker(twins, loop, rng),
        topics=Topics(),
        server_id=SERVER_ID,
        clock=loop.time,
        wall=clock.now,
    )
    t0 = clock.now()
    out = TwinCrossing(outcomes={rid: [] for rid in ids}, seconds=seconds, under_m={0.3: 0.0, 0.25: 0.0})

    async def heartbeat() -> None:
        while True:
            for robot in twins.values():
                robot.heard_heartbeat(SERVER_ID)
            await asyncio.sleep(HEARTBEAT_PERIOD_S)

    async def sample() -> None:
        while True:
            poses = [(t, t.pose()) for t in twins.values()]
            for (ta, a), (tb, b) in itertools.combinations(poses, 2):
                d = math.hypot(a.x - b.x, a.y - b.y)
                if d < out.closest_m:
                    out.closest_m = d
                    out.closest_at = {
                        "t": round(clock.now() - t0, 2),
                        **{t.robot_id: [round(v, 3) for v in (*t.guard.nominal, *t.guard.applied)] for t in (ta, tb)},
                    }
                for bound in out.under_m:
                    if d < bound:
                        out.under_m[bound] += SAMPLE_S
            await asyncio.sleep(SAMPLE_S)

    def free_goal(robot: str, goal_rng: random.Random) -> tuple[float, float]:
        here = registry.robots[robot].position
        hx, hy = (here.x, here.y) if here is not None else (0.0, 0.0)
        taken = [(s.position.x, s.position.y) for r, s in registry.robots.items() if r != robot and s.position]
        while True:
            goal = (goal_rng.uniform(-GOAL_SPAN_M, GOAL_SPAN_M), goal_rng.uniform(-GOAL_SPAN_M, GOAL_SPAN_M))
            if math.dist(goal, (hx, hy)) < MIN_TRIP_M:
                continue
            others = taken + [g for r, g in out.goals.items() if r != robot]
            if all(math.dist(goal, o) > FREE_M for o in others):
                out.goals[robot] = goal
                return goal

    async def operate(k: int, robot: str, deadline: float) -> None:
        goal_rng = random.Random(seed + k)
        while clock.now() < deadline - 5.0:
            x, y = free_goal(robot, goal_rng)
            body = CommandCreate(command="goto", args={"x": x, "y": y, "timeout_s": GOAL_TIMEOUT_S})
            cmd = await commands.create(robot, body)
            while cmd.status not in FINAL_ACK_STATUSES:
                await asyncio.sleep(0.05)
            out.outcomes[robot].append("done" if cmd.status == "done" else f"{cmd.status}: {cmd.reason}")
            await asyncio.sleep(OPERATOR_S)  # a refusal comes at once: the operator's next request takes a moment

    tasks = [
        loop.create_task(publisher.run()),
        loop.create_task(heartbeat()),
        loop.create_task(drive(list(twins.values()), clock)),
    ]
    try:
        await asyncio.sleep(WARM_UP_S)
        tasks.append(loop.create_task(sample()))
        deadline = clock.now() + seconds
        await asyncio.gather(*(operate(k, rid, deadline) for k, rid in enumerate(ids)))
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    out.interventions = sum(t.filter_log.interventions for t in twins.values())
    return out
