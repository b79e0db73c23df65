"""A virtual clock and motors that drive a perfect simulated world: the motion runner's unit tests
(tests/robot_agent/motion/test_runner.py, test_parked.py) run on them without a broker or real time."""

from __future__ import annotations

import asyncio
from typing import Any

from robot_agent.motors.base import MotorDriver
from robot_agent.sim.world import SimWorld


class VirtualClock:
    """A virtual clock: the runner's (robot_agent.motion.clock.Clock) and, called, the simulated world's."""

    def __init__(self) -> None:
        self.t = 100.0
        self.slept: list[float] = []

    def __call__(self) -> float:
        return self.t

    def monotonic(self) -> float:
        return self.t

    def now(self) -> float:
        return 1_700_000_000.0 + self.t

    async def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.t += seconds
        await asyncio.sleep(0)


class RecordingMotors(MotorDriver):
    """Drives a perfect simulated world and remembers every set-point (the hardware is all that is stood in
    for)."""

    def __init__(self, world: SimWorld) -> None:
        self.world = world
        self.sets: list[tuple[float, float]] = []

    @classmethod
    def create(cls, config: Any, world: SimWorld | None) -> MotorDriver:
        raise NotImplementedError

    def set(self, left: float, right: float) -> None:
        self.sets.append((left, right))
        self.world.set_wheels(left, right)

    def stop(self) -> None:
        self.set(0.0, 0.0)

    def operable(self) -> tuple[bool, str]:
        return True, ""
