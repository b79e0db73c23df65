"""Robots still running the original Mollusca framework (the seed design document): their topics, their
command strings and how they are addressed, and the shapes of their Lighthouse positions."""

from __future__ import annotations

import re
from typing import Any, Literal

import orjson

from fleet_protocol.core import ProtocolError, is_valid_robot_id
from fleet_protocol.payloads import PositionData

# Topics of robots still running the original Mollusca framework (see the seed design document).
#: every topic of the old framework starts with this
LEGACY_PREFIX = "robot/"
LEGACY_POSITION_TOPIC = "robot/sensor_data/position"
LEGACY_APRILTAG_TOPIC = "robot/sensor_data/apriltag"
LEGACY_IMU_TOPIC = "robot/sensor_data/imu"
LEGACY_SENSOR_FILTER = "robot/sensor_data/+"
LEGACY_COMMAND_TOPIC = "robot/control/commands"
#: The one seed command that always passes (e-stop, deadman, hold, the server's Last Will).
LEGACY_STOP = "stop"
#: Seed drive strings go at QoS 0: a drive queued for a reconnecting robot must never run late.
#: ``stop`` goes at QoS 1 (a late stop is harmless).
QOS_LEGACY_DRIVE = 0
QOS_LEGACY_STOP = 1
#: Where a robot on the old framework listens: the seed's code subscribes to the shared topic only
#: (so one drive moves every such robot); a robot changed to subscribe to its own topic gets ``own``.
LegacyListensOn = Literal["shared", "own"]
LEGACY_LISTENS_ON_DEFAULT: LegacyListensOn = "shared"


def legacy_command_topics(robot_id: str, listens_on: LegacyListensOn) -> list[str]:
    """The topics a drive for ``robot_id`` goes to: only those it listens on."""
    if listens_on == "own":
        return [legacy_namespaced_command_topic(robot_id)]
    return [LEGACY_COMMAND_TOPIC]


def is_legacy_topic(topic: str) -> bool:
    """A topic of the old framework (``robot/...``), handled by the legacy adapter."""
    return topic.startswith(LEGACY_PREFIX)


def legacy_namespaced_command_topic(robot_id: str) -> str:
    """The per-robot command topic the seed proposes (``{robot_id}/control/commands``)."""
    if not is_valid_robot_id(robot_id):
        raise ProtocolError("bad_robot_id", robot_id[:80])
    return f"{robot_id}/control/commands"


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
