"""Command handling: validation, expiry, the motor gate, the e-stop latch and the drive deadman.

Handlers live in :data:`COMMAND_REGISTRY` (name -> :class:`CommandSpec`); the seed's five commands are
always enabled, others (e.g. ``set_speed``) when the config lists them. A drive handler returns wheel
set-points and a duration; the :class:`CommandHandler` applies them and stops the motors when the
duration ends unless another drive command renewed it first (deadman). Every command is acked
``accepted`` then ``done`` (or ``rejected`` / ``expired``, final at once).
"""

from __future__ import annotations

import asyncio
import collections
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import orjson
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from fleet_protocol import (
    MAX_DRIVE_DURATION_S,
    SEED_COMMANDS,
    Ack,
    AckStatus,
    Command,
    CommandName,
    DriveArgs,
    EStop,
    ProtocolError,
    StopArgs,
    StrictNumber,
    decode_command,
    decode_estop,
    make_ack,
    now,
)
from robot_agent.motors.base import MotorDriver
from robot_agent.util import RejectCounter

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Drive:
    """Wheel set-points (-1..1) to hold for ``duration_s`` (capped at the protocol's maximum)."""

    left: float
    right: float
    duration_s: float


HandlerFn = Callable[[Any, "CommandHandler"], Drive | None]


@dataclass(frozen=True, slots=True)
class CommandSpec:
    name: str
    args_model: type[BaseModel]
    handler: HandlerFn
    #: Moves the robot: subject to the motor gate and refused while the e-stop is latched.
    drives: bool = False


COMMAND_REGISTRY: dict[str, CommandSpec] = {}


def register_command(spec: CommandSpec) -> CommandSpec:
    """Make a handler available; enable it on a robot with ``extra_commands = ["name"]`` in the config."""
    COMMAND_REGISTRY[spec.name] = spec
    return spec


def _speed(args: DriveArgs, h: CommandHandler) -> float:
    return args.speed if "speed" in args.model_fields_set else h.default_speed


def _drive(left: float, right: float) -> HandlerFn:
    def handler(args: DriveArgs, h: CommandHandler) -> Drive:
        s = _speed(args, h)
        return Drive(left * s, right * s, args.duration_s)

    return handler


register_command(CommandSpec(CommandName.MOVE_FORWARD, DriveArgs, _drive(1, 1), drives=True))
register_command(CommandSpec(CommandName.MOVE_BACKWARD, DriveArgs, _drive(-1, -1), drives=True))
# Turning in place: left = counter-clockwise (yaw increasing) = right wheel forward.
register_command(CommandSpec(CommandName.TURN_LEFT, DriveArgs, _drive(-1, 1), drives=True))
register_command(CommandSpec(CommandName.TURN_RIGHT, DriveArgs, _drive(1, -1), drives=True))
register_command(CommandSpec(CommandName.STOP, StopArgs, lambda args, h: None))


class SetSpeedArgs(BaseModel):
    model_config = ConfigDict(extra="forbid")

    speed: StrictNumber = Field(ge=0.0, le=1.0)


def _set_speed(args: SetSpeedArgs, h: CommandHandler) -> None:
    h.default_speed = args.speed


#: Example extension: the speed drive commands use when they give none.
register_command(CommandSpec("set_speed", SetSpeedArgs, _set_speed))


@dataclass
class _ActiveDrive:
    command_id: str
    timer: asyncio.TimerHandle


class CommandHandler:
    """Runs on the asyncio loop; ``send_ack`` publishes an :class:`Ack` (QoS 1)."""

    def __init__(
        self,
        motors: MotorDriver,
        send_ack: Callable[[Ack], None],
        extra_commands: list[str] | None = None,
        on_state_change: Callable[[], None] | None = None,
        clock: Callable[[], float] = now,
    ) -> None:
        self.motors = motors
        self._send_ack = send_ack
        self._on_state_change = on_state_change or (lambda: None)
        self._clock = clock
        names = [str(n) for n in SEED_COMMANDS]
        for extra in extra_commands or []:
            if extra not in COMMAND_REGISTRY:
                raise ValueError(f"unknown command handler {extra!r} (known: {', '.join(COMMAND_REGISTRY)})")
            if extra not in names:
                names.append(extra)
        self.specs: dict[str, CommandSpec] = {n: COMMAND_REGISTRY[n] for n in names}
        self.default_speed = 0.5
        self.estop_engaged = False
        self.estop_id: str | None = None
        self.rejects = RejectCounter(log)
        self.executed: list[str] = []  # ids of commands that reached a handler (tests, diagnostics)
        self._active: _ActiveDrive | None = None
        self._seen: collections.OrderedDict[str, None] = collections.OrderedDict()

    @property
    def command_names(self) -> list[str]:
        return list(self.specs)

    @property
    def driving(self) -> bool:
        return self._active is not None

    def _ack(self, command_id: str, status: AckStatus, reason: str = "") -> None:
        try:
            self._send_ack(make_ack(command_id, status, reason[:500]))
        except Exception:
            log.exception("sending ack failed")

    # ------------------------------------------------------------------------------------------------
    def handle_payload(self, payload: bytes) -> None:
        """Entry point for a raw ``cmd`` message; never raises."""
        try:
            cmd = decode_command(payload)
        except ProtocolError as exc:
            self.rejects.reject(exc.reason, exc.detail)
            cid = _salvage_id(payload)
            if cid is not None:
                self._ack(cid, AckStatus.REJECTED, f"bad command: {exc.detail[:200]}")
            return
        try:
            self.handle(cmd)
        except Exception as exc:  # a handler bug must not take the agent down
            log.exception("command %s failed", cmd.command)
            self._stop_motors()
            self._ack(cmd.id, AckStatus.REJECTED, f"internal error: {exc}")

    def handle(self, cmd: Command) -> None:
        if cmd.id in self._seen:  # QoS 1 redelivery: already handled
            return
        self._seen[cmd.id] = None
        if len(self._seen) > 512:
            self._seen.popitem(last=False)

        at = self._clock()
        if cmd.expired(at):
            self.rejects.reject("expired", f"{cmd.command} {cmd.id}")
            self._ack(
                cmd.id, AckStatus.EXPIRED, f"expired {at - cmd.ts - cmd.ttl_s:.3f}s ago (ttl {cmd.ttl_s}s)"
            )
            return
        spec = self.specs.get(cmd.command)
        if spec is None:
            self.rejects.reject("unknown_command", cmd.command)
            self._ack(cmd.id, AckStatus.REJECTED, f"unknown command {cmd.command!r}")
            return
        try:
            args = spec.args_model.model_validate(cmd.args)
        except ValidationError as exc:
            detail = "; ".join(
                f"{'.'.join(str(p) for p in e['loc']) or 'args'}: {e['msg']}"
                for e in exc.errors(include_url=False)
            )
            self.rejects.reject("bad_args", f"{cmd.command}: {detail}")
            self._ack(cmd.id, AckStatus.REJECTED, f"bad args: {detail}")
            return
        if spec.drives:
            if self.estop_engaged:
                self._ack(cmd.id, AckStatus.REJECTED, "e-stop engaged")
                return
            ok, why = self.motors.operable()
            if not ok:
                self._ack(cmd.id, AckStatus.REJECTED, f"motor not operable: {why}")
                return
        self.executed.append(cmd.id)
        del self.executed[:-256]
        result = spec.handler(args, self)
        if isinstance(result, Drive):
            self._start_drive(cmd.id, result)
        elif cmd.command == CommandName.STOP:
            self._ack(cmd.id, AckStatus.ACCEPTED)
            self._end_active("stopped")
            self._stop_motors()
            self._ack(cmd.id, AckStatus.DONE)
        else:
            self._ack(cmd.id, AckStatus.ACCEPTED)
            self._ack(cmd.id, AckStatus.DONE)

    # ------------------------------------------------------------------------------------------------
    def _start_drive(self, command_id: str, drive: Drive) -> None:
        duration = min(max(drive.duration_s, 0.0), MAX_DRIVE_DURATION_S)
        try:
            self.motors.set(drive.left, drive.right)
        except Exception as exc:
            self._stop_motors()
            self._ack(command_id, AckStatus.REJECTED, f"motor error: {exc}")
            return
        self._ack(command_id, AckStatus.ACCEPTED)
        self._end_active("superseded", stop=False)
        loop = asyncio.get_running_loop()
        self._active = _ActiveDrive(command_id, loop.call_later(duration, self._deadman, command_id))

    def _deadman(self, command_id: str) -> None:
        if self._active is None or self._active.command_id != command_id:
            return
        self._active = None
        self._stop_motors()
        self._ack(command_id, AckStatus.DONE)

    def _end_active(self, reason: str, stop: bool = True) -> None:
        active, self._active = self._active, None
        if active is None:
            return
        active.timer.cancel()
        if stop:
            self._stop_motors()
        self._ack(active.command_id, AckStatus.DONE, reason)

    def _stop_motors(self) -> None:
        try:
            self.motors.stop()
        except Exception:
            log.exception("motor stop failed")

    def stop_all(self, reason: str) -> None:
        """Stop now (link lost, shutdown); the running drive is acked done with ``reason``."""
        self._end_active(reason)
        self._stop_motors()

    # ------------------------------------------------------------------------------------------------
    def handle_estop_payload(self, payload: bytes) -> None:
        """``fleet/estop``: anything arriving here stops the robot; a valid message sets the latch."""
        try:
            msg = decode_estop(payload)
        except ProtocolError as exc:
            self.rejects.reject("bad_estop", f"{exc.reason}: {exc.detail}")
            self.stop_all("e-stop (malformed message)")
            return
        self.handle_estop(msg)

    def handle_estop(self, msg: EStop) -> None:
        changed = msg.engaged != self.estop_engaged or msg.id != self.estop_id
        if msg.engaged:
            self.stop_all("e-stop")
        if not changed:
            return
        self.estop_engaged = msg.engaged
        self.estop_id = msg.id
        if msg.engaged:
            log.warning(
                "E-STOP engaged (%s): drive commands refused until released", msg.reason or "no reason"
            )
        else:
            log.warning("e-stop released (%s)", msg.reason or "no reason")
        if msg.id:
            self._ack(msg.id, AckStatus.DONE, "stopped" if msg.engaged else "released")
        self._on_state_change()


def _salvage_id(payload: bytes) -> str | None:
    """The ``id`` of an invalid command, if one can be read, so the sender gets a rejection."""
    try:
        obj = orjson.loads(payload)
    except (orjson.JSONDecodeError, TypeError):
        return None
    if isinstance(obj, dict):
        cid = obj.get("id")
        if isinstance(cid, str) and 0 < len(cid) <= 64:
            return cid
    return None
