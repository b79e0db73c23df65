"""Commands and acks: the seed's drive commands and their arguments, the command envelope, ack statuses."""

from __future__ import annotations

import uuid
from enum import StrEnum
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from fleet_protocol.core import (
    DEFAULT_COMMAND_TTL_S,
    DEFAULT_DRIVE_DURATION_S,
    MAX_COMMAND_TTL_S,
    MAX_DRIVE_DURATION_S,
    _finite,
    _Wire,
    now,
)


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
#: Every command that can move a robot: refused while the fleet e-stop or the robot's hold is latched.
MOVING_COMMANDS: frozenset[str] = frozenset({*DRIVE_COMMANDS, "drive", "goto", "follow_path"})
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
    #: A goal (goto, follow_path) that ended without reaching it; ``reason`` starts with a MotionFailure.
    FAILED = "failed"
    #: A goal ended by a stop, another motion command or the e-stop.
    ABORTED = "aborted"


FINAL_ACK_STATUSES = frozenset(
    {AckStatus.REJECTED, AckStatus.DONE, AckStatus.EXPIRED, AckStatus.FAILED, AckStatus.ABORTED}
)


class Ack(_Wire):
    id: str = Field(min_length=1, max_length=64)
    status: AckStatus
    reason: str = Field(default="", max_length=500)
    ts: float

    _ts = field_validator("ts")(_finite)


def new_command(command: str, args: dict[str, Any] | None = None, ttl_s: float = DEFAULT_COMMAND_TTL_S) -> Command:
    return Command(id=str(uuid.uuid4()), command=command, args=args or {}, ts=now(), ttl_s=ttl_s)


def make_ack(command_id: str, status: AckStatus, reason: str = "") -> Ack:
    return Ack(id=command_id, status=status, reason=reason, ts=now())
