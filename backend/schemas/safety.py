"""Safety and control: the e-stop, a robot's hold, the control lease, and the audit log and events that
record them."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field


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
    #: who pressed (or released) it: the user or token name and the client ("ada via ui")
    source: str = ""
    acks: dict[str, str]


class HoldCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    reason: str = Field(default="", max_length=500)


class HoldPublic(BaseModel):
    """A robot's stop latch: stopped and its drives refused until released."""

    held: bool
    ts: float
    reason: str
    source: str


class LeasePublic(BaseModel):
    """Who drives a robot now. It lapses ``lapse_s`` after ``last_drive``."""

    robot_id: str
    holder: str
    holder_name: str
    acquired_at: float
    last_drive: float
    via: str = ""
    lapse_s: float = 60.0


class LeaseGrant(BaseModel):
    model_config = ConfigDict(extra="forbid")

    #: the requester's holder id, as the ``lease_request`` live message gave it
    to_holder: str = Field(min_length=1, max_length=160)
    #: ignored (kept so that older clients are not refused): the server names the holder itself
    to_name: str = Field(default="", max_length=160)


class AuditEntry(BaseModel):
    id: int
    ts: float
    actor: str
    actor_name: str
    token_id: str | None
    client: str
    action: str
    robot_id: str | None
    detail: dict[str, Any]


class EventPublic(BaseModel):
    ts: float
    kind: str
    robot_id: str | None
    detail: dict[str, Any]
