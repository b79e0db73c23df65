"""A command's arguments, checked before it goes out: the protocol's models for the commands the server
knows (the seed's drives, stop, and the motion commands ``drive``, ``goto``, ``follow_path``: NaN, huge
numbers or 10,000 waypoints get a 422 here and never reach a robot); a robot-specific command's args are the
robot's to check."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ValidationError

from backend.core.errors import ServiceError, format_errors
from fleet_protocol import DRIVE_COMMANDS, MOTION_ARGS, CommandName, DriveArgs, StopArgs

ARG_MODELS: dict[str, type[BaseModel]] = {
    **{c: DriveArgs for c in DRIVE_COMMANDS},
    CommandName.STOP: StopArgs,
    **MOTION_ARGS,
}


class CommandError(ServiceError):
    """A command refused (404 unknown robot, 409 offline / e-stop / held / lease, 422 bad args, 503)."""


def checked_args(command: str, args: dict[str, Any]) -> dict[str, object]:
    """The args as the robot gets them (validated and normalised), or a 422 that says what is wrong."""
    model = ARG_MODELS.get(command)
    if model is None:
        return dict(args)  # robot-specific command: the robot validates its own args
    try:
        return model.model_validate(args).model_dump()
    except ValidationError as exc:
        raise CommandError(422, f"bad args for {command!r}: {format_errors(exc)}", "bad_args") from None
