"""Encoding and decoding: JSON with orjson, each inbound payload validated against its schema; a payload
that does not follow the protocol raises :class:`ProtocolError` with a short reason."""

from __future__ import annotations

from typing import Any

import orjson
from pydantic import BaseModel, ValidationError

from fleet_protocol.commands import Ack, Command
from fleet_protocol.core import _M, MAX_JSON_PAYLOAD_BYTES, ProtocolError, now
from fleet_protocol.health import HealthData
from fleet_protocol.payloads import (
    AprilTagData,
    EStop,
    ImuData,
    LighthouseGeometry,
    PositionData,
    RobotHold,
    ServerHeartbeat,
    ServerSync,
    Status,
    Telemetry,
)

# Stream name -> schema of its ``data`` object. Streams not listed are stored as opaque JSON objects.
STREAM_SCHEMAS: dict[str, type[BaseModel]] = {
    "position": PositionData,
    "imu": ImuData,
    "lighthouse_geometry": LighthouseGeometry,
    "apriltag": AprilTagData,
    "health": HealthData,
}

#: streams a robot publishes retained and rarely (the base stations' geometry): the server keeps the last one
#: per robot, replays it to every new live client, and clears the retained topic when it forgets a robot
RETAINED_STREAMS = frozenset({"lighthouse_geometry"})


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


def encode_telemetry(seq: int, data: dict[str, Any], ts: float | None = None, boot: str | None = None) -> bytes:
    body: dict[str, Any] = {"ts": now() if ts is None else ts, "seq": seq, "data": data}
    if boot is not None:
        body["boot"] = boot
    return orjson.dumps(body)


def decode_heartbeat(payload: bytes) -> ServerHeartbeat:
    return _validate(ServerHeartbeat, _load_json(payload), "bad_heartbeat")


def decode_sync(payload: bytes) -> ServerSync:
    return _validate(ServerSync, _load_json(payload), "bad_sync")


def decode_hold(payload: bytes) -> RobotHold:
    """An empty payload clears a retained hold: treated as released."""
    if not payload:
        return RobotHold(held=False, ts=now(), reason="retained hold cleared")
    return _validate(RobotHold, _load_json(payload), "bad_hold")
