"""The JSON payloads robots and servers exchange (except commands and acks: fleet_protocol.commands)."""

from __future__ import annotations

from typing import Any

from pydantic import Field, field_validator

from fleet_protocol.core import _finite, _Wire


class Capabilities(_Wire):
    sensors: list[str] = Field(default_factory=list, max_length=64)
    commands: list[str] = Field(default_factory=list, max_length=64)


class SensorState(_Wire):
    """Health of one sensor plugin, reported in the status message."""

    ok: bool = True
    error: str | None = None
    rate_hz: float | None = None


class Status(_Wire):
    online: bool
    ts: float
    agent_version: str = ""
    capabilities: Capabilities = Field(default_factory=Capabilities)
    legacy: bool = False
    estop: bool = False
    sensors: dict[str, SensorState] = Field(default_factory=dict)
    #: Telemetry messages dropped from the offline buffer since start.
    buffer_dropped: int = 0
    #: The agent's MQTT keepalive. It publishes something (telemetry, or this status again) at least every
    #: half of it, so the server shows the robot offline after 1.5 x this without a message, sooner than
    #: the broker's Last Will (Mosquitto checks keepalives only every few seconds).
    keepalive_s: float | None = Field(default=None, gt=0, le=3600)
    #: The agent runs the safety filter of issue 31 (docs/autonomy.md): its neighbours may count on it to take
    #: its half of the avoidance. Older agents omit it: they are obstacles, like robots on the old framework.
    collision_filter: bool = False
    #: Clock sync (optional; older agents omit them): the server's clock minus the robot's, in ms, as
    #: measured over time/req + time/resp (null until measured), and the round trip of that measurement.
    clock_synced: bool | None = None
    clock_offset_ms: float | None = None
    clock_rtt_ms: float | None = None
    #: The agent's wire protocol version (PROTOCOL_VERSION); null from agents older than the health stream.
    protocol_version: int | None = Field(default=None, ge=0)

    _ts = field_validator("ts")(_finite)


#: an agent's boot id: new at every agent start, because ``seq`` starts again at 0 then
BOOT_ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"


class Telemetry(_Wire):
    ts: float
    seq: int = Field(ge=0, lt=2**63, strict=True)  # strict: `true` or 1.0 is not a sequence number
    data: dict[str, Any]
    #: which run of the agent ``seq`` counts in (optional: older agents and legacy robots send none)
    boot: str | None = Field(default=None, pattern=BOOT_ID_PATTERN)

    _ts = field_validator("ts")(_finite)


class PositionData(_Wire):
    x: float
    y: float
    z: float = 0.0
    yaw: float | None = None

    @field_validator("x", "y", "z", "yaw")
    @classmethod
    def _check_finite(cls, v: float | None) -> float | None:
        return None if v is None else _finite(v)


class ImuData(_Wire):
    accel: list[float] = Field(min_length=3, max_length=3)
    gyro: list[float] = Field(min_length=3, max_length=3)

    @field_validator("accel", "gyro")
    @classmethod
    def _check_finite(cls, v: list[float]) -> list[float]:
        return [_finite(x) for x in v]


class BaseStation(_Wire):
    id: int | str
    position: list[float] = Field(min_length=3, max_length=3)
    rotation: list[list[float]] = Field(min_length=3, max_length=3)


class LighthouseGeometry(_Wire):
    base_stations: list[BaseStation]


def _finite_list(v: list[float]) -> list[float]:
    return [_finite(x) for x in v]


class CameraInfo(_Wire):
    """Pinhole intrinsics (pixels) the AprilTag poses were computed with."""

    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float

    _f = field_validator("fx", "fy", "cx", "cy")(_finite)


class EulerDeg(_Wire):
    """The seed's get_Euler angles of ``rotation`` in degrees (R = Rz(yaw) Ry(pitch) Rx(roll))."""

    roll: float
    pitch: float
    yaw: float

    _f = field_validator("roll", "pitch", "yaw")(_finite)


class AprilTagDetection(_Wire):
    """One tag in one frame; pose of the tag in the camera frame (x right, y down, z forward), mm."""

    tag_id: int = Field(ge=0)
    family: str = Field(max_length=32)
    corners: list[list[float]] = Field(min_length=4, max_length=4)
    center: list[float] = Field(min_length=2, max_length=2)
    translation_mm: list[float] = Field(min_length=3, max_length=3)
    rotation: list[list[float]] = Field(min_length=3, max_length=3)
    euler_deg: EulerDeg
    decision_margin: float
    pose_error: float

    _f = field_validator("center", "translation_mm")(_finite_list)
    _g = field_validator("decision_margin", "pose_error")(_finite)

    @field_validator("corners")
    @classmethod
    def _check_corners(cls, v: list[list[float]]) -> list[list[float]]:
        if any(len(row) != 2 for row in v):
            raise ValueError("each corner is [u, v]")
        return [_finite_list(row) for row in v]

    @field_validator("rotation")
    @classmethod
    def _check_rotation(cls, v: list[list[float]]) -> list[list[float]]:
        if any(len(row) != 3 for row in v):
            raise ValueError("rotation is a 3x3 matrix")
        return [_finite_list(row) for row in v]


class AprilTagData(_Wire):
    """``apriltag`` stream: the detections of one camera frame (``frame_seq`` matches the camera stream)."""

    frame_seq: int = Field(ge=0)
    image_size: list[int] = Field(min_length=2, max_length=2)
    camera: CameraInfo
    detections: list[AprilTagDetection] = Field(default_factory=list, max_length=256)


class EStop(_Wire):
    """``fleet/estop``. ``engaged=false`` releases a latched e-stop."""

    ts: float
    #: Robots ack an e-stop on their ``ack`` topic with this id, so the UI can show who stopped.
    id: str | None = Field(default=None, max_length=64)
    engaged: bool = True
    reason: str = Field(default="", max_length=500)
    source: str = Field(default="", max_length=120)

    _ts = field_validator("ts")(_finite)


#: Each server replica publishes a heartbeat this often; silence for HEARTBEAT_SILENCE_S means "no server".
HEARTBEAT_PERIOD_S = 0.2
HEARTBEAT_SILENCE_S = 1.0
QOS_HEARTBEAT = 0
QOS_HOLD = 1


class ServerHeartbeat(_Wire):
    """``{prefix}/heartbeat``: a server replica is alive. ``legacy_topics`` are the seed command topics
    it may have driven, so that a sentinel beside the broker can stop them when the server goes silent."""

    server_id: str = Field(min_length=1, max_length=64)
    ts: float
    seq: int = Field(ge=0)
    legacy_topics: list[str] = Field(default_factory=list, max_length=1024)

    _ts = field_validator("ts")(_finite)


class RobotHold(_Wire):
    """``{prefix}/{robot}/hold`` (retained): "hold this robot" - stopped, its drives refused until released."""

    held: bool
    ts: float
    #: new for every hold and release (optional: servers before it sent none); with ``ts`` it orders two
    #: states of one hold, as the e-stop's id does (docs/safety.md, "The e-stop survives anything")
    id: str | None = Field(default=None, max_length=64)
    reason: str = Field(default="", max_length=500)
    source: str = Field(default="", max_length=120)

    _ts = field_validator("ts")(_finite)


QOS_SYNC = 1


class ServerSync(_Wire):
    """``{prefix}/sync``: a server's marker to itself after each (re)connection. The broker delivers the
    retained e-stop and holds of the subscriptions made just before it first, so when the marker comes back
    the server knows what the broker holds (possibly nothing: a broker restarted empty) and puts back what
    it has lost. Every replica hears every marker and heeds only its own."""

    server_id: str = Field(min_length=1, max_length=64)
    nonce: str = Field(min_length=1, max_length=64)
