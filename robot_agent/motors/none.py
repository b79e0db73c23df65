"""No motors (a sensor-only robot, or motors not configured): every drive command is refused by the gate."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

from robot_agent.motors.base import MotorDriver


class NoMotorConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    type: Literal["none"] = "none"


class NoMotorDriver(MotorDriver):
    @classmethod
    def create(cls, config: Any, world: Any) -> NoMotorDriver:
        return cls()

    def set(self, left: float, right: float) -> None:
        raise RuntimeError("no motor driver configured")

    def stop(self) -> None:
        pass

    def operable(self) -> tuple[bool, str]:
        return False, "no motor driver configured ([motors] in the agent config)"
