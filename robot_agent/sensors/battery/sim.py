"""The simulated robot's battery: it drains with motor use, so readiness and alarms can be exercised.

Usage is the sim motor driver's integral of the mean absolute wheel set-point over time
(:meth:`SimMotorDriver.wheel_usage_s`), so a short drive between two samples still counts. The voltage
follows the charge linearly between ``empty_v`` and ``full_v``.
"""

from __future__ import annotations

import time
from typing import Any

from pydantic import Field

from robot_agent.sensors.battery.base import BatteryReading, BatterySource, VoltageRangeConfig


class SimBatteryConfig(VoltageRangeConfig):
    type: str = "sim"
    #: charge at agent start, % (``--battery-start-pct``)
    start_pct: float = Field(default=100.0, ge=0.0, le=100.0)
    #: % used per second of driving at full speed on both wheels
    drain_pct_per_s: float = Field(default=0.5, ge=0.0, le=100.0)
    #: % used per hour standing still (electronics)
    idle_drain_pct_per_h: float = Field(default=2.0, ge=0.0, le=100.0)


class SimBattery(BatterySource):
    type_name = "sim"
    config_model = SimBatteryConfig

    def __init__(self, config: Any, shared: dict[str, Any]) -> None:
        super().__init__(config, shared)
        assert isinstance(config, SimBatteryConfig)
        self.cfg = config
        self._started = time.monotonic()

    def open(self) -> None:
        if not callable(getattr(self.shared.get("motors"), "wheel_usage_s", None)):
            raise RuntimeError("battery type 'sim' needs the sim motor driver (run with --simulate)")

    def percent(self) -> float:
        usage_s = float(self.shared["motors"].wheel_usage_s())
        idle_h = (time.monotonic() - self._started) / 3600.0
        used = usage_s * self.cfg.drain_pct_per_s + idle_h * self.cfg.idle_drain_pct_per_h
        return max(0.0, self.cfg.start_pct - used)

    def read(self) -> BatteryReading:
        pct = self.percent()
        volts = self.cfg.empty_v + (self.cfg.full_v - self.cfg.empty_v) * pct / 100.0
        return BatteryReading(voltage_v=round(volts, 3), percent=round(pct, 2))
