"""Commands: what a client sends, and a command with its acknowledgements as the API shows it."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from fleet_protocol import COMMAND_NAME_PATTERN, MAX_COMMAND_TTL_S, StrictNumber

#: ``failed`` and ``aborted``: a goal (goto, follow_path) that ended without reaching it, or ended by a stop
CommandStatus = Literal["sent", "accepted", "rejected", "done", "expired", "timeout", "failed", "aborted"]


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
