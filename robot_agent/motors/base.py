"""The motor driver interface: a two-motor differential drive with a health gate (the seed's
``check_motor_status``)."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any

from robot_agent.motors.watchdog import MotorWatchdog

if TYPE_CHECKING:
    from robot_agent.sim.world import SimWorld


class MotorConfigError(ValueError):
    """The ``[motors]`` config is invalid or names an unknown driver."""


class MotorDriver(ABC):
    """Drive set-points are fractions of full speed in -1..1 (positive = forward) per side.

    Drivers implement :meth:`set` and :meth:`stop`; the command handler calls :meth:`drive` and :meth:`halt`,
    which add the :class:`MotorWatchdog` for every driver: set-points given with a lease are zeroed by a
    thread of their own when nobody refreshes them in time.
    """

    _motor_watchdog: MotorWatchdog | None = None

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

    @property
    def motor_fault(self) -> bool | None:
        """The health stream's ``motor_fault``: True/False when the driver can tell, None when it cannot
        (no fault line). Drivers that sense a fault override this; the default knows nothing."""
        return None

    # -- the entry points of the command handler ---------------------------------------------------------
    @property
    def watchdog(self) -> MotorWatchdog:
        if self._motor_watchdog is None:  # created on first use: drivers need not call a base __init__
            self._motor_watchdog = MotorWatchdog(self.stop)
        return self._motor_watchdog

    def drive(self, left: float, right: float, lease_s: float | None) -> None:
        """:meth:`set`, to be refreshed within ``lease_s`` (None: no watchdog, a debug switch only)."""
        wd = self.watchdog
        with wd.lock:
            if lease_s is None:
                wd.disarm()
            else:
                wd.arm(lease_s)
            self.set(left, right)

    def halt(self) -> None:
        """:meth:`stop` and release the watchdog."""
        wd = self.watchdog
        with wd.lock:
            wd.disarm()
            self.stop()

    def shutdown(self) -> None:
        """:meth:`close` (never while the watchdog stops the motors), then end the watchdog's thread."""
        wd = self.watchdog
        try:
            with wd.lock:
                wd.disarm()
                self.close()
        finally:
            wd.close()


def clamp_unit(v: float) -> float:
    """A wheel set-point within -1..1. NaN or an infinity (a broken estimate, a bad value) is 0: it never
    moves a robot (``min``/``max`` would pass NaN on to the motors)."""
    v = float(v)
    return min(max(v, -1.0), 1.0) if math.isfinite(v) else 0.0
