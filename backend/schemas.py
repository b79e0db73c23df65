"""API shapes (request and response models), kept apart from the database tables."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from fleet_protocol import COMMAND_NAME_PATTERN, MAX_COMMAND_TTL_S, StrictNumber

CommandStatus = Literal["sent", "accepted", "rejected", "done", "expired", "timeout"]


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


class CommandCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    command: str = Field(pattern=COMMAND_NAME_PATTERN, examples=["move_forward"])
    args: dict[str, Any] = Field(default_factory=dict, examples=[{"speed": 0.5, "duration_s": 1.0}])
    ttl_s: StrictNumber | None = Field(default=None, gt=0, le=MAX_COMMAND_TTL_S)
    source: str = Field(default="rest", min_length=1, max_length=120)


class AckPublic(BaseModel):
    status: str
    reason: str
    ts: float
    received_ts: float


class CommandPublic(BaseModel):
    id: str
    robot_id: str
    command: str
    args: dict[str, Any]
    source: str
    ts: float
    ttl_s: float
    status: CommandStatus
    reason: str
    acks: list[AckPublic]


class TelemetryPoint(BaseModel):
    ts: float
    seq: int
    data: dict[str, Any]


class TelemetryPage(BaseModel):
    robot_id: str
    stream: str
    downsampled: bool
    #: ``none`` raw points; ``bucket-mean-minmax`` (position: per time bucket the mean of x/y/z plus
    #: ``x_min``/``x_max``... and the bucket's last yaw); ``bucket-last`` (other streams: the last point
    #: of each bucket).
    method: Literal["none", "bucket-mean-minmax", "bucket-last"]
    points: list[TelemetryPoint]


class StreamStats(BaseModel):
    stream: str
    count: int
    first_ts: float | None
    last_ts: float | None
    last_seq: int | None = None
    #: Sequence numbers never received (counted since this server started).
    gaps: int = 0
    #: Messages with a seq not above the last one (redeliveries, reordering) since this server started.
    out_of_order: int = 0
    #: Times the seq went back to 0 (agent restart).
    restarts: int = 0


class MqttHealth(BaseModel):
    url: str | None  # null for unauthenticated callers
    connected: bool


class DatabaseHealth(BaseModel):
    url: str | None  # null for unauthenticated callers
    ok: bool


class HealthPublic(BaseModel):
    status: Literal["ok", "degraded"]
    version: str
    #: "on", or "off" (FLEET_AUTH=off: demo only)
    auth: Literal["on", "off"] = "on"
    mqtt: MqttHealth
    database: DatabaseHealth
    rejects: dict[str, Any] | None  # null for unauthenticated callers


class EStopCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    reason: str = Field(default="", max_length=500)
    source: str = Field(default="rest", max_length=120)


class EStopEngaged(BaseModel):
    id: str
    ts: float
    engaged: bool
    robots: list[str]


class EStopPublic(BaseModel):
    engaged: bool
    ts: float | None
    id: str | None
    reason: str
    acks: dict[str, str]


class EventPublic(BaseModel):
    ts: float
    kind: str
    robot_id: str | None
    detail: dict[str, Any]
