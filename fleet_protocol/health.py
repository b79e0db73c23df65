"""The ``health`` stream's payload: what a robot knows about its own fitness, once a second.

Every field is optional. A field the robot cannot measure (no battery monitor configured, no Wi-Fi
interface, clock not yet synced) is ``null``: a consumer (readiness, alarms) must read ``null`` as
"unknown", never as a good or bad value.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field, field_validator

_FLOAT_FIELDS = (
    "battery_v",
    "battery_pct",
    "battery_a",
    "cpu_temp_c",
    "cpu_load",
    "mem_used_pct",
    "disk_free_mb",
    "wifi_rssi_dbm",
    "wifi_bitrate_mbps",
    "clock_offset_ms",
    "uptime_s",
    "system_uptime_s",
)


class HealthData(BaseModel):
    """``data`` of ``fleet/{id}/telemetry/health`` (see docs/protocol.md, "Health")."""

    model_config = ConfigDict(extra="ignore")

    #: battery pack voltage, V, and charge, % (0..100): from the configured battery source
    battery_v: float | None = Field(default=None, ge=0.0, le=1000.0)
    battery_pct: float | None = Field(default=None, ge=0.0, le=100.0)
    #: battery current, A (positive = discharging), when the source measures it (INA219)
    battery_a: float | None = None
    #: SoC temperature, degrees C
    cpu_temp_c: float | None = Field(default=None, ge=-100.0, le=300.0)
    #: CPU utilisation of all cores since the previous sample, % (0..100)
    cpu_load: float | None = Field(default=None, ge=0.0, le=100.0)
    mem_used_pct: float | None = Field(default=None, ge=0.0, le=100.0)
    #: free space on the agent's data file system, MB
    disk_free_mb: float | None = Field(default=None, ge=0.0)
    wifi_interface: str | None = Field(default=None, max_length=32)
    wifi_rssi_dbm: float | None = Field(default=None, ge=-200.0, le=30.0)
    wifi_bitrate_mbps: float | None = Field(default=None, ge=0.0, le=100_000.0)
    #: the server's clock minus the robot's, ms (the agent's clock sync); null until synced
    clock_offset_ms: float | None = None
    #: seconds since the agent process started, and since the machine booted
    uptime_s: float | None = Field(default=None, ge=0.0)
    system_uptime_s: float | None = Field(default=None, ge=0.0)
    agent_version: str | None = Field(default=None, max_length=64)
    protocol_version: int | None = Field(default=None, ge=0)
    #: True when the motor driver reports a fault, False when it reports none, null when it cannot tell
    motor_fault: bool | None = None
    #: the driver's reason when ``motor_fault`` is true
    motor_fault_reason: str | None = Field(default=None, max_length=300)
    #: the safety filter heard the fleet's poses in the last 0.5 s (false: it creeps and new goals wait);
    #: null once a site turned the filter off (a site without avoidance), and from older agents
    hears_poses: bool | None = None

    @field_validator(*_FLOAT_FIELDS)
    @classmethod
    def _finite(cls, v: float | None) -> float | None:
        if v is not None and not math.isfinite(v):
            raise ValueError("must be a finite number or null")
        return v


HEALTH_FIELDS: tuple[str, ...] = tuple(HealthData.model_fields)
