"""Robots still running the original Mollusca MQTT module (see the seed design document).

They publish ``robot/sensor_data/{position,apriltag,imu}`` as ``{"robot_id", "<kind>_data"|"position": ...}``
without seq or timestamp, anonymously: so only robots an admin registered (registrations.py) are heard, and
a message naming any other robot is refused (``legacy_unregistered``, counted and logged). They show in the
fleet marked ``legacy``: online while they publish (offline
after ``legacy_offline_after_s`` of silence, done by the registry tick), their data stored with the
server's receive time and a server-side per-stream seq. Commands go to them as plain strings (see
CommandService). IMU/AprilTag payloads that match the fleet schemas are stored on the ``imu``/``apriltag``
streams; other shapes are kept verbatim on ``legacy_imu``/``legacy_apriltag`` as ``{"value": ...}``.
"""

from __future__ import annotations

from typing import Any, Protocol

import orjson
from pydantic import BaseModel, ValidationError

from backend.comms.base import InboundMessage
from backend.core.rejects import InboundRejects
from backend.services.fleet.registry import Registry, RobotState
from backend.services.legacy.relay import LegacyCommandRelay
from backend.services.telemetry.ingest import TelemetryIngest
from fleet_protocol import (
    LEGACY_APRILTAG_TOPIC,
    LEGACY_IMU_TOPIC,
    LEGACY_POSITION_TOPIC,
    MAX_JSON_PAYLOAD_BYTES,
    SEED_COMMANDS,
    AprilTagData,
    ImuData,
    ProtocolError,
    RobotHold,
    is_valid_robot_id,
)

#: topic -> (payload key, fleet stream, schema, fallback stream)
_KINDS: dict[str, tuple[str, str, type[BaseModel] | None, str]] = {
    LEGACY_POSITION_TOPIC: ("position", "position", None, "position"),
    LEGACY_APRILTAG_TOPIC: ("apriltag_data", "apriltag", AprilTagData, "legacy_apriltag"),
    LEGACY_IMU_TOPIC: ("imu_data", "imu", ImuData, "legacy_imu"),
}


class Holds(Protocol):
    """What the bridge needs of the holds (safety): an old robot that appears shows the hold retained for it,
    and is told to stop at once when a hold blocks it (safety imports this domain, so it is a protocol)."""

    def attach(self, st: RobotState) -> None: ...

    def blocking(self, st: RobotState, unit: list[str]) -> tuple[str, RobotHold] | None: ...


class LegacyAdapter:
    def __init__(
        self,
        registry: Registry,
        ingest: TelemetryIngest,
        rejects: InboundRejects,
        *,
        relay: LegacyCommandRelay,
        holds: Holds,
    ) -> None:
        self._relay = relay
        self._holds = holds
        self._registry = registry
        self._ingest = ingest
        self._rejects = rejects
        self._seq: dict[tuple[str, str], int] = {}

    def handle(self, msg: InboundMessage) -> None:
        kind = _KINDS.get(msg.topic)
        if kind is None:
            raise ProtocolError("legacy_unknown_topic", msg.topic[:120])
        key, stream, schema, fallback = kind
        if len(msg.payload) > MAX_JSON_PAYLOAD_BYTES:
            raise ProtocolError("oversize", f"{len(msg.payload)} bytes")
        try:
            obj = orjson.loads(msg.payload)
        except orjson.JSONDecodeError as exc:
            raise ProtocolError("bad_json", str(exc)[:200]) from None
        if not isinstance(obj, dict):
            raise ProtocolError("bad_legacy", "payload is not a JSON object")
        robot_id = obj.get("robot_id")
        if not isinstance(robot_id, str) or not is_valid_robot_id(robot_id):
            raise ProtocolError("bad_robot_id", repr(robot_id)[:80])
        if key not in obj:
            raise ProtocolError("bad_legacy", f"missing {key!r}")
        value = obj[key]
        if stream == "position":
            data = self._position(value)
        else:
            data, stream = self._typed(value, schema, stream, fallback)
        self._accept(robot_id, stream, data, msg.received)

    @staticmethod
    def _position(value: Any) -> dict[str, Any]:
        from fleet_protocol import parse_position_text

        pos = parse_position_text(value)
        return {"x": pos.x, "y": pos.y, "z": pos.z, "yaw": pos.yaw}

    @staticmethod
    def _typed(value: Any, schema: type[BaseModel] | None, stream: str, fallback: str) -> tuple[dict[str, Any], str]:
        if schema is not None and isinstance(value, dict):
            try:
                return schema.model_validate(value).model_dump(mode="json"), stream
            except ValidationError:
                pass
        return {"value": value}, fallback

    def _accept(self, robot_id: str, stream: str, data: dict[str, Any], received: float) -> None:
        st = self._registry.get(robot_id)
        if st is None or not st.legacy:
            # anyone who may write the shared anonymous topics could otherwise speak for any robot
            raise ProtocolError(
                "legacy_unregistered",
                f"{robot_id!r} is not registered as a robot on the old framework (fleet-server robots legacy-add)",
            )
        caps = st.capabilities
        changed = list(caps.commands) != list(SEED_COMMANDS) or stream not in caps.sensors
        if changed:
            caps.commands = list(SEED_COMMANDS)
            if stream not in caps.sensors:
                caps.sensors.append(stream)
            st.dirty = True
        if not st.online:
            self._holds.attach(st)
            self._registry.set_online(st, True, received, "legacy")
            # no e-stop or hold of its own: one that appears while latched hears "stop" at once
            self._relay.on_appeared(st, held=self._holds.blocking(st, self._registry.legacy_unit(st)) is not None)
        elif changed:
            self._registry.push(st)
        seq = self._seq.get((robot_id, stream), -1) + 1
        self._seq[(robot_id, stream)] = seq
        self._ingest.ingest(robot_id, stream, received, seq, data, received, legacy=True)
