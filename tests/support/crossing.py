"""Robots on random crossing gotos (issue 31's acceptance): each robot, again and again, is sent somewhere in the
pool a metre or more away, where no robot is and no other is going, as an operator would send it; the ways
cross. Shared by tests/robot_agent/motion/test_collision_guard.py (60 s) and bench/bench_collisions.py (5 min)."""

from __future__ import annotations

import math
import random
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from fleet_client import CommandFailed, FleetClient, FleetError

#: a free goal: this far from every other robot and every other robot's goal (the safety distance and more: a
#: goal next to a parked robot can never be reached)
FREE_M = 0.7
#: goals within this square (m): the 4 m pool less its geofence margin and a body
GOAL_SPAN_M = 1.6
#: a goal at least this far from where the robot is
MIN_TRIP_M = 1.0
BLOCKED = "failed: blocked: no progress for 1"


def ring(n: int, radius: float = 1.2, prefix: str = "cx") -> list[tuple[str, float, float, float]]:
    """Start poses: ``n`` robots on a circle."""
    return [
        (f"{prefix}-{k}", radius * math.cos(2 * math.pi * k / n), radius * math.sin(2 * math.pi * k / n), 0.0)
        for k in range(n)
    ]


@dataclass
class Crossing:
    """What became of every goal: ``done`` or the final ack's status and reason."""

    outcomes: dict[str, list[str]] = field(default_factory=dict)
    goals: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def results(self) -> list[str]:
        return [o for found in self.outcomes.values() for o in found]

    @property
    def done(self) -> int:
        return self.results.count("done")

    @property
    def blocked(self) -> int:
        return sum(o.startswith(BLOCKED) for o in self.results)


def run_crossing(fleet: FleetClient, robots: list[str], seconds: float, seed: int = 1000) -> Crossing:
    """Every robot on goals for ``seconds`` (its last goal is sent no later than 5 s before the end and waited
    for); a thread and a client each, as separate operators."""
    out = Crossing(outcomes={r: [] for r in robots})
    lock = threading.Lock()
    deadline = time.monotonic() + seconds

    def free_goal(c: FleetClient, robot: str, rng: random.Random) -> tuple[float, float]:
        fleet_now = {r["id"]: r.get("position") for r in c.robots()}
        here = fleet_now.get(robot) or {"x": 0.0, "y": 0.0}
        taken = [(p["x"], p["y"]) for r, p in fleet_now.items() if r != robot and p]
        while True:
            goal = (rng.uniform(-GOAL_SPAN_M, GOAL_SPAN_M), rng.uniform(-GOAL_SPAN_M, GOAL_SPAN_M))
            if math.dist(goal, (here["x"], here["y"])) < MIN_TRIP_M:
                continue
            with lock:
                others = taken + [g for r, g in out.goals.items() if r != robot]
                if all(math.dist(goal, o) > FREE_M for o in others):
                    out.goals[robot] = goal
                    return goal

    def operate(k: int, robot: str) -> None:
        rng = random.Random(seed + k)
        with FleetClient(fleet.url, token=fleet.token) as c:
            while time.monotonic() < deadline - 5.0:
                x, y = free_goal(c, robot, rng)
                try:
                    c.goto(robot, x, y, timeout_s=40.0, wait_timeout=45.0)
                    out.outcomes[robot].append("done")
                except CommandFailed as exc:
                    cmd: dict[str, Any] = exc.command
                    out.outcomes[robot].append(f"{cmd.get('status')}: {cmd.get('reason', '')}")
                except FleetError as exc:  # a goal inside another robot's body: refused, pick another
                    if exc.code != "goal_inside_robot":
                        raise
                    time.sleep(0.2)

    threads = [threading.Thread(target=operate, args=(k, r), daemon=True) for k, r in enumerate(robots)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(seconds + 60)
    return out
