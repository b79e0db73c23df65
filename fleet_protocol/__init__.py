"""The Mollusca Fleet wire protocol: every topic name and payload schema, shared by agent and server.

This is the only module that knows how topics are spelled. The topic prefix (default ``fleet``) is
added in exactly one place, :class:`Topics`. Payloads are JSON (orjson) except camera frames, which are
binary JPEG with a small binary header (see :func:`encode_camera_frame`).

Human-readable description: ``docs/protocol.md``. Keep the two in step.
"""

from __future__ import annotations

import math
import re
import struct
import time
import uuid
from dataclasses import dataclass
from enum import StrEnum
from typing import Annotated, Any, Literal, TypeVar

import orjson
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

PROTOCOL_VERSION = 1
DEFAULT_PREFIX = "fleet"

ROBOT_ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"
_ROBOT_ID_RE = re.compile(ROBOT_ID_PATTERN)
STREAM_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"
_STREAM_RE = re.compile(STREAM_PATTERN)
_PREFIX_RE = re.compile(r"^[A-Za-z0-9_-]+(/[A-Za-z0-9_-]+)*$")

#: Largest JSON payload either side accepts; larger messages are refused and counted.
MAX_JSON_PAYLOAD_BYTES = 256 * 1024
#: Largest camera frame payload (a 640x480 JPEG is ~30-80 kB).
MAX_CAMERA_PAYLOAD_BYTES = 2 * 1024 * 1024

QOS_TELEMETRY = 1
QOS_STATUS = 1
QOS_COMMAND = 1
QOS_ACK = 1
QOS_ESTOP = 1
QOS_CAMERA = 0
QOS_PING = 0

#: While a drive runs, the agent checks its broker link by a round trip every LINK_PING_PERIOD_S and stops
#: the motors when no echo came back for LINK_SILENCE_S (a frozen link, not yet noticed by TCP/keepalive).
LINK_PING_PERIOD_S = 0.1
LINK_SILENCE_S = 0.35

# Drive safety limits (seconds).
DEFAULT_DRIVE_DURATION_S = 0.5
MAX_DRIVE_DURATION_S = 5.0
DEFAULT_COMMAND_TTL_S = 2.0
MAX_COMMAND_TTL_S = 60.0


_M = TypeVar("_M", bound=BaseModel)


class ProtocolError(ValueError):
    """A topic or payload that does not follow the protocol. ``reason`` is a short counter label."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail


def is_valid_robot_id(robot_id: str) -> bool:
    return bool(_ROBOT_ID_RE.match(robot_id))


def is_valid_stream(stream: str) -> bool:
    return bool(_STREAM_RE.match(stream))


def now() -> float:
    """Wall-clock epoch seconds: every ``ts`` on the wire."""
    return time.time()


# --------------------------------------------------------------------------------------------------
# Topics
# --------------------------------------------------------------------------------------------------


class TopicKind(StrEnum):
    STATUS = "status"
    TELEMETRY = "telemetry"
    CMD = "cmd"
    ACK = "ack"
    CAMERA = "camera"
    ESTOP = "estop"


@dataclass(frozen=True, slots=True)
class ParsedTopic:
    kind: TopicKind
    robot_id: str | None = None
    stream: str | None = None


class Topics:
    """Builds and parses topic names under one prefix. The only place the prefix is applied."""

    def __init__(self, prefix: str = DEFAULT_PREFIX) -> None:
        prefix = prefix.strip("/")
        if not _PREFIX_RE.match(prefix):
            raise ValueError(f"invalid topic prefix {prefix!r}")
        self.prefix = prefix
        self._prefix_parts = len(prefix.split("/"))

    def _robot(self, robot_id: str, *rest: str) -> str:
        if not is_valid_robot_id(robot_id):
            raise ProtocolError("bad_robot_id", robot_id[:80])
        return "/".join((self.prefix, robot_id, *rest))

    # -- concrete topics
    def status(self, robot_id: str) -> str:
        return self._robot(robot_id, "status")

    def telemetry(self, robot_id: str, stream: str) -> str:
        if not is_valid_stream(stream):
            raise ProtocolError("bad_stream", stream[:80])
        return self._robot(robot_id, "telemetry", stream)

    def cmd(self, robot_id: str) -> str:
        return self._robot(robot_id, "cmd")

    def ack(self, robot_id: str) -> str:
        return self._robot(robot_id, "ack")

    def camera(self, robot_id: str) -> str:
        return self._robot(robot_id, "camera")

    def ping(self, robot_id: str) -> str:
        """The agent's own link probe: it publishes here (QoS 0) and listens to itself while driving."""
        return self._robot(robot_id, "ping")

    def estop(self) -> str:
        return f"{self.prefix}/estop"

    # -- subscription filters
    def all_status(self) -> str:
        return f"{self.prefix}/+/status"

    def all_telemetry(self) -> str:
        return f"{self.prefix}/+/telemetry/+"

    def all_acks(self) -> str:
        return f"{self.prefix}/+/ack"

    def all_commands(self) -> str:
        return f"{self.prefix}/+/cmd"

    def all_camera(self) -> str:
        return f"{self.prefix}/+/camera"

    def parse(self, topic: str) -> ParsedTopic:
        """Classify an incoming topic; raises :class:`ProtocolError` for anything not ours or malformed."""
        parts = topic.split("/")
        n = self._prefix_parts
        if "/".join(parts[:n]) != self.prefix:
            raise ProtocolError("foreign_topic", topic[:120])
        rest = parts[n:]
        if rest == ["estop"]:
            return ParsedTopic(TopicKind.ESTOP)
        if len(rest) < 2:
            raise ProtocolError("bad_topic", topic[:120])
        robot_id = rest[0]
        if not is_valid_robot_id(robot_id):
            raise ProtocolError("bad_robot_id", robot_id[:80])
        kind = rest[1]
        if kind == "telemetry" and len(rest) == 3:
            if not is_valid_stream(rest[2]):
                raise ProtocolError("bad_stream", rest[2][:80])
            return ParsedTopic(TopicKind.TELEMETRY, robot_id, rest[2])
        if len(rest) == 2 and kind in ("status", "cmd", "ack", "camera"):
            return ParsedTopic(TopicKind(kind), robot_id)
        raise ProtocolError("bad_topic", topic[:120])


# Topics of robots still running the original Mollusca framework (see the seed design document).
LEGACY_POSITION_TOPIC = "robot/sensor_data/position"
LEGACY_APRILTAG_TOPIC = "robot/sensor_data/apriltag"
LEGACY_IMU_TOPIC = "robot/sensor_data/imu"
LEGACY_SENSOR_FILTER = "robot/sensor_data/+"
LEGACY_COMMAND_TOPIC = "robot/control/commands"


def legacy_namespaced_command_topic(robot_id: str) -> str:
    """The per-robot command topic the seed proposes (``{robot_id}/control/commands``)."""
    if not is_valid_robot_id(robot_id):
        raise ProtocolError("bad_robot_id", robot_id[:80])
    return f"{robot_id}/control/commands"


# --------------------------------------------------------------------------------------------------
# Payloads
# --------------------------------------------------------------------------------------------------


def _finite(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError("must be a finite number")
    return v


class _Wire(BaseModel):
    """Base for inbound payloads: unknown fields are tolerated (forward compatibility)."""

    model_config = ConfigDict(extra="ignore", frozen=False)


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

    _ts = field_validator("ts")(_finite)


class Telemetry(_Wire):
    ts: float
    seq: int = Field(ge=0, lt=2**63, strict=True)  # strict: `true` or 1.0 is not a sequence number
    data: dict[str, Any]

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


class CommandName(StrEnum):
    MOVE_FORWARD = "move_forward"
    MOVE_BACKWARD = "move_backward"
    TURN_LEFT = "turn_left"
    TURN_RIGHT = "turn_right"
    STOP = "stop"


DRIVE_COMMANDS: tuple[str, ...] = (
    CommandName.MOVE_FORWARD,
    CommandName.MOVE_BACKWARD,
    CommandName.TURN_LEFT,
    CommandName.TURN_RIGHT,
)
SEED_COMMANDS: tuple[str, ...] = (*DRIVE_COMMANDS, CommandName.STOP)
COMMAND_NAME_PATTERN = r"^[a-z][a-z0-9_]{0,63}$"


#: A JSON number, never ``true``/``false``: lax validation reads booleans as 1 and 0, so a drive command
#: with ``"speed": true`` would run at full speed and an API call with ``"ttl_s": true`` would mean 1 s.
StrictNumber = Annotated[float, Field(strict=True)]


class DriveArgs(BaseModel):
    """Arguments of the drive commands. ``duration_s`` is the deadman: the drive stops after it."""

    model_config = ConfigDict(extra="forbid")

    speed: StrictNumber = Field(default=0.5, ge=0.0, le=1.0)
    duration_s: StrictNumber = Field(default=DEFAULT_DRIVE_DURATION_S, gt=0.0, le=MAX_DRIVE_DURATION_S)


class StopArgs(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Command(_Wire):
    id: str = Field(min_length=1, max_length=64)
    command: str = Field(pattern=COMMAND_NAME_PATTERN)
    args: dict[str, Any] = Field(default_factory=dict)
    ts: float
    ttl_s: float = Field(default=DEFAULT_COMMAND_TTL_S, gt=0.0, le=MAX_COMMAND_TTL_S)

    _ts = field_validator("ts")(_finite)

    def expired(self, at: float | None = None) -> bool:
        return (now() if at is None else at) > self.ts + self.ttl_s


class AckStatus(StrEnum):
    ACCEPTED = "accepted"
    REJECTED = "rejected"
    DONE = "done"
    EXPIRED = "expired"


FINAL_ACK_STATUSES = frozenset({AckStatus.REJECTED, AckStatus.DONE, AckStatus.EXPIRED})


class Ack(_Wire):
    id: str = Field(min_length=1, max_length=64)
    status: AckStatus
    reason: str = Field(default="", max_length=500)
    ts: float

    _ts = field_validator("ts")(_finite)


class EStop(_Wire):
    """``fleet/estop``. ``engaged=false`` releases a latched e-stop."""

    ts: float
    #: Robots ack an e-stop on their ``ack`` topic with this id, so the UI can show who stopped.
    id: str | None = Field(default=None, max_length=64)
    engaged: bool = True
    reason: str = Field(default="", max_length=500)
    source: str = Field(default="", max_length=120)

    _ts = field_validator("ts")(_finite)


_POSITION_SPLIT_RE = re.compile(r"[\s,;]+")


def parse_position_text(value: Any) -> PositionData:
    """Parse a legacy Lighthouse position in any of the shapes today's robots send.

    Accepts ``"x,y,z"``, ``"[x, y, z]"``, ``"x y z"`` (also numpy's ``"[x y z]"``), a JSON list, a JSON
    object ``{"x","y","z"[,"yaw"]}`` (as text or already decoded), bytes of any of these. Anything else raises
    :class:`ProtocolError` ``bad_position``. Shared by the agent's UDP input and the server's legacy adapter.
    """
    if isinstance(value, bytes | bytearray):
        try:
            value = bytes(value).decode("utf-8")
        except UnicodeDecodeError:
            raise ProtocolError("bad_position", "not UTF-8") from None
    if isinstance(value, str):
        text = value.strip()
        if len(text) > 1000:
            raise ProtocolError("bad_position", "too long")
        if text.startswith("{"):
            try:
                value = orjson.loads(text)
            except orjson.JSONDecodeError:
                raise ProtocolError("bad_position", repr(text[:80])) from None
        else:
            if text[:1] in "[(" and text[-1:] in "])":
                text = text[1:-1]
            parts = [p for p in _POSITION_SPLIT_RE.split(text.strip()) if p]
            if len(parts) != 3:
                raise ProtocolError("bad_position", f"expected 3 numbers: {value[:80]!r}")
            value = parts
    try:
        if isinstance(value, dict):
            return PositionData.model_validate(value)
        if isinstance(value, list | tuple) and len(value) == 3 and not any(isinstance(v, bool) for v in value):
            x, y, z = (float(v) for v in value)
            return PositionData(x=x, y=y, z=z)
    except (ValueError, TypeError) as exc:  # ValidationError is a ValueError
        raise ProtocolError("bad_position", str(exc)[:200]) from None
    raise ProtocolError("bad_position", f"unsupported shape: {str(value)[:80]!r}")


# Stream name -> schema of its ``data`` object. Streams not listed are stored as opaque JSON objects.
STREAM_SCHEMAS: dict[str, type[BaseModel]] = {
    "position": PositionData,
    "imu": ImuData,
    "lighthouse_geometry": LighthouseGeometry,
    "apriltag": AprilTagData,
}

# --------------------------------------------------------------------------------------------------
# Encoding / decoding
# --------------------------------------------------------------------------------------------------


def dumps(obj: BaseModel | dict[str, Any]) -> bytes:
    if isinstance(obj, BaseModel):
        obj = obj.model_dump(mode="json", exclude_none=False)
    return orjson.dumps(obj)


def _load_json(payload: bytes) -> Any:
    if len(payload) > MAX_JSON_PAYLOAD_BYTES:
        raise ProtocolError("oversize", f"{len(payload)} bytes")
    try:
        return orjson.loads(payload)
    except orjson.JSONDecodeError as exc:
        raise ProtocolError("bad_json", str(exc)[:200]) from None


def _validate(model: type[_M], obj: Any, reason: str) -> _M:
    if not isinstance(obj, dict):
        raise ProtocolError(reason, "payload is not a JSON object")
    try:
        return model.model_validate(obj)
    except ValidationError as exc:
        raise ProtocolError(reason, exc.errors(include_url=False, include_input=False).__repr__()[:300]) from None


def decode_status(payload: bytes) -> Status:
    return _validate(Status, _load_json(payload), "bad_status")


def decode_telemetry(payload: bytes, stream: str) -> Telemetry:
    """Decode a telemetry envelope and, for known streams, validate its ``data``."""
    msg = _validate(Telemetry, _load_json(payload), "bad_telemetry")
    schema = STREAM_SCHEMAS.get(stream)
    if schema is not None:
        msg.data = _validate(schema, msg.data, f"bad_{stream}").model_dump(mode="json")
    return msg


def decode_command(payload: bytes) -> Command:
    return _validate(Command, _load_json(payload), "bad_command")


def decode_ack(payload: bytes) -> Ack:
    return _validate(Ack, _load_json(payload), "bad_ack")


def decode_estop(payload: bytes) -> EStop:
    """An empty payload clears a retained e-stop on the broker; it is treated as a release."""
    if not payload:
        return EStop(ts=now(), engaged=False, reason="retained e-stop cleared")
    return _validate(EStop, _load_json(payload), "bad_estop")


def encode_telemetry(seq: int, data: dict[str, Any], ts: float | None = None) -> bytes:
    return orjson.dumps({"ts": now() if ts is None else ts, "seq": seq, "data": data})


def new_command(command: str, args: dict[str, Any] | None = None, ttl_s: float = DEFAULT_COMMAND_TTL_S) -> Command:
    return Command(id=str(uuid.uuid4()), command=command, args=args or {}, ts=now(), ttl_s=ttl_s)


def make_ack(command_id: str, status: AckStatus, reason: str = "") -> Ack:
    return Ack(id=command_id, status=status, reason=reason, ts=now())


# --------------------------------------------------------------------------------------------------
# Camera frames: binary payload = magic, header length, JSON header, JPEG bytes.
# --------------------------------------------------------------------------------------------------

CAMERA_MAGIC = b"MFC1"
_CAMERA_HDR = struct.Struct(">4sI")


class CameraHeader(_Wire):
    frame_seq: int = Field(ge=0)
    ts: float
    width: int = Field(gt=0, le=10000)
    height: int = Field(gt=0, le=10000)
    format: Literal["jpeg"] = "jpeg"


def encode_camera_frame(header: CameraHeader, jpeg: bytes) -> bytes:
    hdr = header.model_dump_json().encode()
    return _CAMERA_HDR.pack(CAMERA_MAGIC, len(hdr)) + hdr + jpeg


def decode_camera_frame(payload: bytes) -> tuple[CameraHeader, bytes]:
    if len(payload) > MAX_CAMERA_PAYLOAD_BYTES:
        raise ProtocolError("oversize", f"{len(payload)} bytes")
    if len(payload) < _CAMERA_HDR.size or payload[:4] != CAMERA_MAGIC:
        raise ProtocolError("bad_camera", "missing frame header")
    _, hlen = _CAMERA_HDR.unpack_from(payload)
    end = _CAMERA_HDR.size + hlen
    if hlen > 4096 or end > len(payload):
        raise ProtocolError("bad_camera", "bad header length")
    header = _validate(CameraHeader, _load_json(payload[_CAMERA_HDR.size : end]), "bad_camera")
    return header, payload[end:]


__all__ = [name for name in dir() if not name.startswith("_")]
