"""The motor driver interface: a two-motor differential drive with a health gate (the seed's
``check_motor_status``)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from robot_agent.sim.world import SimWorld


class MotorConfigError(ValueError):
    """The ``[motors]`` config is invalid or names an unknown driver."""


class MotorDriver(ABC):
    """Drive set-points are fractions of full speed in -1..1 (positive = forward) per side."""

    @classmethod
    @abstractmethod
    def create(cls, config: Any, world: SimWorld | None) -> MotorDriver:
        """Build the driver from its validated config model."""

    @abstractmethod
    def set(self, left: float, right: float) -> None:
        """Apply wheel set-points; values outside -1..1 are clamped."""

    @abstractmethod
    def stop(self) -> None:
        """Stop both motors now. Must never raise for an operable or already-stopped driver."""

    @abstractmethod
    def operable(self) -> tuple[bool, str]:
        """(True, "") when drive commands may run; else (False, why)."""

    def close(self) -> None:
        """Stop and release the hardware."""
        self.stop()


def clamp_unit(v: float) -> float:
    return min(max(float(v), -1.0), 1.0)
