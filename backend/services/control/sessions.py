"""An off-board controller's session: velocity set-points from one WebSocket turned into ``drive`` commands.

Each set-point goes through :class:`~backend.services.control.commands.CommandService` like a REST command, so
everything that guards a drive applies unchanged: the e-stop, a robot's hold, the battery alarm, the
control lease, the audit trail and the per-caller rate. What the socket saves is an HTTP request per
set-point (a connection, headers, authentication and a JSON response): the set-point is published as soon
as its frame is read. The robot's own deadman (``duration_s``) stops it when the set-points stop coming;
when the socket closes the session also sends ``stop`` at once, so a controller that ends or crashes
leaves no robot running out its last set-point.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import orjson
from pydantic import ValidationError

from backend.core.errors import ServiceError, format_errors
from backend.schemas import CommandCreate
from backend.schemas.control import CONTROL_MESSAGE, ControlDrive, ControlStop
from backend.services.access.audit import Actor
from backend.services.control.commands import CommandService
from fleet_protocol import CommandName

log = logging.getLogger(__name__)

#: A set-point's command may still start this long after it was sent (its deadman ends it sooner anyway).
CONTROL_TTL_S = 1.0
MAX_CONTROL_MESSAGE = 4096


class ControlSession:
    """One control socket driving ``robot_id`` for ``actor``; ``reply`` queues a message for the client.
    ``take_rate`` is the caller's command token bucket (seconds to wait, 0 when allowed)."""

    def __init__(
        self,
        *,
        robot_id: str,
        actor: Actor,
        commands: CommandService,
        reply: Callable[[bytes], None],
        take_rate: Callable[[], float],
        source: str = "control",
    ) -> None:
        self.robot_id = robot_id
        self._actor = actor
        self._commands = commands
        self._reply = reply
        self._take_rate = take_rate
        self._source = source[:120]
        #: until when the robot may still be running on this session's last drive (monotonic)
        self._driving_until = 0.0
        self.sent = 0
        self.refused = 0

    def _error(self, ref: Any, code: str, detail: str) -> None:
        self.refused += 1
        self._reply(orjson.dumps({"type": "error", "ref": ref, "code": code, "detail": detail[:500]}))

    async def handle(self, raw: str | bytes) -> None:
        """One client message; a refusal is answered with an ``error`` message, never raised."""
        if len(raw) > MAX_CONTROL_MESSAGE:
            self._error(None, "too_large", f"message over {MAX_CONTROL_MESSAGE} bytes")
            return
        try:
            msg = CONTROL_MESSAGE.validate_python(orjson.loads(raw))
        except orjson.JSONDecodeError as exc:
            self._error(None, "bad_message", f"not JSON: {exc}")
            return
        except ValidationError as exc:
            ref = _salvage_ref(raw)
            self._error(ref, "bad_message", format_errors(exc))
            return
        if isinstance(msg, ControlDrive):
            await self._drive(msg)
        else:
            await self._stop(msg)

    async def _drive(self, msg: ControlDrive) -> None:
        wait = self._take_rate()
        if wait > 0:
            self._error(msg.ref, "rate_limited", f"over the command rate for this robot; retry in {wait:.2f} s")
            return
        args = {"linear": msg.linear, "angular": msg.angular, "duration_s": msg.duration_s}
        body = CommandCreate(command="drive", args=args, ttl_s=CONTROL_TTL_S, source=self._source)
        try:
            cmd = await self._commands.create(self.robot_id, body, self._actor)
        except ServiceError as exc:
            self._error(msg.ref, exc.code, exc.detail)
            return
        self.sent += 1
        self._driving_until = time.monotonic() + msg.duration_s
        self._reply(orjson.dumps({"type": "sent", "ref": msg.ref, "id": cmd.id, "command": "drive", "ts": cmd.ts}))

    async def _stop(self, msg: ControlStop) -> None:
        try:
            cmd = await self._commands.create(
                self.robot_id, CommandCreate(command=CommandName.STOP, source=self._source), self._actor
            )
        except ServiceError as exc:
            self._error(msg.ref, exc.code, exc.detail)
            return
        self._driving_until = 0.0
        self._reply(orjson.dumps({"type": "sent", "ref": msg.ref, "id": cmd.id, "command": "stop", "ts": cmd.ts}))

    async def close(self) -> None:
        """The socket closed: stop the robot if it may still be running on one of our set-points."""
        if time.monotonic() >= self._driving_until:
            return
        self._driving_until = 0.0
        try:
            await self._commands.stop_now(self.robot_id, f"{self._source} closed")
        except ServiceError as exc:  # offline, broker gone: its deadman stops it
            log.warning("stop after the control socket of %s closed not sent: %s", self.robot_id, exc.detail)


def _salvage_ref(raw: str | bytes) -> Any:
    """The ``ref`` of an invalid message, when one can be read, so the client can match the error."""
    try:
        obj = orjson.loads(raw)
    except orjson.JSONDecodeError:
        return None
    ref = obj.get("ref") if isinstance(obj, dict) else None
    return ref if isinstance(ref, int | str) and not isinstance(ref, bool) and len(str(ref)) <= 64 else None
