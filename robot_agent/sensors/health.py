"""Health: the robot's fitness to run, once a second, on the ``health`` stream (schema: HealthData).

Battery (a configurable source: INA219, a HAT's file, the simulator), SoC temperature, CPU, memory, disk,
Wi-Fi, the clock offset the agent measured, uptimes, versions and the motor driver's fault state. Every
field is measured or null: a reader that fails gives null for its fields and the others still publish.
The agent puts its clock sync and motor driver into ``ctx.shared`` ("clock", "motors").
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from pydantic import Field, field_validator

from fleet_common.ratelimit import RateLimitedLogger
from fleet_protocol import PROTOCOL_VERSION, HealthData
from robot_agent import __version__
from robot_agent.sensors.base import SensorConfig, SensorContext, SensorPlugin
from robot_agent.sensors.battery import (
    BatteryConfig,
    BatteryReading,
    BatterySource,
    create_battery_source,
    validate_battery_config,
)
from robot_agent.sensors.sysinfo import SystemReader
from robot_agent.sensors.wifi import WifiReader

log = logging.getLogger(__name__)


class HealthConfig(SensorConfig):
    type: str = "health"
    rate_hz: float = Field(default=1.0, gt=0.0, le=10.0)
    #: ``[sensors.battery]``: ``type`` = "none" (default), "ina219", "file" or "sim", plus its options
    battery: BatteryConfig = Field(default_factory=lambda: validate_battery_config({"type": "none"}))
    #: Wi-Fi interface to report; None = the first one in /proc/net/wireless
    wifi_interface: str | None = Field(default=None, min_length=1, max_length=32)
    #: file system whose free space is reported
    disk_path: Path = Path("/")

    @field_validator("battery", mode="before")
    @classmethod
    def _battery(cls, v: Any) -> BatteryConfig:
        if isinstance(v, BatteryConfig):
            return v
        if not isinstance(v, dict):
            raise ValueError("battery must be a table with a type")
        return validate_battery_config(v)


class HealthPlugin(SensorPlugin):
    type_name = "health"
    default_stream = "health"
    config_model = HealthConfig
    payload_model = HealthData

    def __init__(self, config: SensorConfig, ctx: SensorContext, *, battery: BatterySource | None = None) -> None:
        """``battery``: a ready source instead of the one ``config.battery`` describes (tests, benchmarks)."""
        super().__init__(config, ctx)
        assert isinstance(config, HealthConfig)
        self.cfg = config
        self.battery: BatterySource = battery or create_battery_source(config.battery, ctx.shared)
        self.system = SystemReader(disk_path=config.disk_path)
        self.wifi = WifiReader(config.wifi_interface)
        self._errors = RateLimitedLogger(log, 60.0)

    async def start(self) -> None:
        self.battery.open()

    async def stop(self) -> None:
        self.wifi.close()
        self.battery.close()

    def _battery(self) -> BatteryReading:
        try:
            return self.battery.read()
        except Exception as exc:  # an I2C error, a half-written file: this sample has no battery values
            self._errors.warning("battery", "battery %s: %s", self.cfg.battery.type, exc)
            return BatteryReading()

    def _motor_fault(self) -> tuple[bool | None, str | None]:
        motors = self.ctx.shared.get("motors")
        if motors is None:
            return None, None
        fault: bool | None = motors.motor_fault
        if not fault:
            return fault, None
        _, why = motors.operable()
        return True, why or None

    def _hears_poses(self) -> bool | None:
        guard = self.ctx.shared.get("collision_guard")
        return None if guard is None else guard.hears_poses()

    def sample(self) -> dict[str, Any]:
        """One health sample (synchronous: the benchmark times exactly this)."""
        bat = self._battery()
        interface, rssi, rate = self.wifi.read()
        clock = self.ctx.shared.get("clock")
        fault, fault_reason = self._motor_fault()
        sysr = self.system
        return {
            "battery_v": bat.voltage_v,
            "battery_pct": bat.percent,
            "battery_a": bat.current_a,
            "cpu_temp_c": sysr.cpu_temp_c(),
            "cpu_load": sysr.cpu_load(),
            "mem_used_pct": sysr.mem_used_pct(),
            "disk_free_mb": sysr.disk_free_mb(),
            "wifi_interface": interface,
            "wifi_rssi_dbm": rssi,
            "wifi_bitrate_mbps": rate,
            "clock_offset_ms": clock.offset_ms() if clock is not None else None,
            "uptime_s": sysr.agent_uptime_s(),
            "system_uptime_s": sysr.system_uptime_s(),
            "agent_version": __version__,
            "protocol_version": PROTOCOL_VERSION,
            "motor_fault": fault,
            "motor_fault_reason": fault_reason,
            "hears_poses": self._hears_poses(),
        }

    async def read(self) -> dict[str, Any] | None:
        return self.sample()
