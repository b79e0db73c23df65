"""Robots as the API shows them: their state, capabilities, position, legacy addressing, and forgetting one."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from backend.schemas.safety import HoldPublic, LeasePublic


class CapabilitiesPublic(BaseModel):
    sensors: list[str] = Field(default_factory=list)
    commands: list[str] = Field(default_factory=list)


class SensorStatePublic(BaseModel):
    ok: bool = True
    error: str | None = None
    rate_hz: float | None = None


class PositionPublic(BaseModel):
    x: float
    y: float
    z: float = 0.0
    yaw: float | None = None
    ts: float


class RobotPublic(BaseModel):
    id: str
    online: bool
    last_seen: float | None
    stale: bool
    agent_version: str
    legacy: bool
    estop: bool
    capabilities: CapabilitiesPublic
    sensors: dict[str, SensorStatePublic]
    position: PositionPublic | None
    msg_rate: float
    #: robots on the old framework: "shared" (the seed's code) or "own" command topic; None otherwise
    legacy_listens_on: Literal["shared", "own"] | None = None
    #: robots on the old framework: every robot one drive to this one moves (the shared topic's listeners)
    legacy_unit: list[str] = Field(default_factory=list)
    hold: HoldPublic | None = None
    #: the control lease: who drives it now (null when nobody does)
    lease: LeasePublic | None = None
    #: fit to go: online, a position fix, battery, clock, motors, no critical alarm (the reasons when not)
    ready: bool = False
    not_ready_reasons: list[str] = Field(default_factory=list)
    #: its open alarms (active or acknowledged), as kind -> severity
    alarms: dict[str, str] = Field(default_factory=dict)


class LegacyAddressing(BaseModel):
    """Which command topic a robot on the old framework listens on."""

    model_config = ConfigDict(extra="forbid")

    listens_on: Literal["shared", "own"]


class LegacyRegistration(BaseModel):
    """Register a robot on the old framework: the command topic it listens on (the seed's code: ``shared``)."""

    model_config = ConfigDict(extra="forbid")

    listens_on: Literal["shared", "own"] = "shared"


TelemetryChoice = Literal["keep", "delete"]


class RobotForgotten(BaseModel):
    robot_id: str
    telemetry: TelemetryChoice
    #: telemetry rows deleted (0 when kept)
    rows_deleted: int
