"""Messages a client sends on the control WebSocket (``/ws/control/{robot_id}``)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from fleet_protocol import DEFAULT_DRIVE_DURATION_S, MAX_DRIVE_DURATION_S, FiniteNumber
from fleet_protocol.motion import MAX_ANGULAR_RPS, MAX_LINEAR_MPS

#: A client's own tag for a message, echoed in the reply (``sent`` / ``error``): an int or a short string.
Ref = int | Annotated[str, Field(max_length=64)] | None


class ControlDrive(BaseModel):
    """A velocity set-point: sent to the robot as a ``drive`` command (its deadman is ``duration_s``)."""

    model_config = ConfigDict(extra="forbid")

    type: Literal["drive"]
    linear: FiniteNumber = Field(ge=-MAX_LINEAR_MPS, le=MAX_LINEAR_MPS)
    angular: FiniteNumber = Field(default=0.0, ge=-MAX_ANGULAR_RPS, le=MAX_ANGULAR_RPS)
    duration_s: FiniteNumber = Field(default=DEFAULT_DRIVE_DURATION_S, gt=0.0, le=MAX_DRIVE_DURATION_S)
    ref: Ref = None


class ControlStop(BaseModel):
    """Stop the robot now (a ``stop`` command: it needs no control lease)."""

    model_config = ConfigDict(extra="forbid")

    type: Literal["stop"]
    ref: Ref = None


ControlMessage = Annotated[ControlDrive | ControlStop, Field(discriminator="type")]
CONTROL_MESSAGE: TypeAdapter[ControlDrive | ControlStop] = TypeAdapter(ControlMessage)
