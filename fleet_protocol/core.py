"""What every part of the protocol shares: its version, limits, QoS levels, the error type, id checks and
the base of every inbound payload."""

from __future__ import annotations

import math
import re
import time
from typing import TypeVar

from pydantic import BaseModel, ConfigDict

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
#: Clock-sync requests and answers (fleet_protocol.clock): a late sample is useless, never queue one.
QOS_TIME = 0
#: gap repair requests (server -> robot) and replies (robot -> server): see fleet_protocol.repair
QOS_REPAIR = 1

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


def _finite(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError("must be a finite number")
    return v


class _Wire(BaseModel):
    """Base for inbound payloads: unknown fields are tolerated (forward compatibility)."""

    model_config = ConfigDict(extra="ignore", frozen=False)
