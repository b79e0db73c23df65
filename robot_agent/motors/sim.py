"""Simulated motors: set the wheel speeds of the :class:`SimWorld`."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

from robot_agent.motors.base import MotorConfigError, MotorDriver, clamp_unit
from robot_agent.sim.world import SimWorld


class SimMotorConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    type: Literal["sim"] = "sim"
    #: Simulate a motor fault (e.g. "overcurrent"): drive commands are then rejected by the gate.
    fault: str | None = None


class SimMotorDriver(MotorDriver):
    def __init__(self, world: SimWorld, fault: str | None = None) -> None:
        self.world = world
        self.fault = fault
        self.left = 0.0
        self.right = 0.0

    @classmethod
    def create(cls, config: Any, world: SimWorld | None) -> SimMotorDriver:
        if world is None:
            raise MotorConfigError("the sim motor driver needs the simulated world (run with --simulate)")
        assert isinstance(config, SimMotorConfig)
        return cls(world, config.fault)

    def set(self, left: float, right: float) -> None:
        self.left, self.right = clamp_unit(left), clamp_unit(right)
        self.world.set_wheels(self.left, self.right)

    def stop(self) -> None:
        self.left = self.right = 0.0
        self.world.set_wheels(0.0, 0.0)

    def operable(self) -> tuple[bool, str]:
        if self.fault:
            return False, f"simulated fault: {self.fault}"
        return True, ""
