"""Command handling: validation, expiry, the motor gate, the e-stop latch and the drive deadman.

Handlers live in :data:`COMMAND_REGISTRY` (name -> :class:`CommandSpec`); the seed's five commands are
always enabled, others (e.g. ``set_speed``) when the config lists them. A drive handler returns wheel
set-points and a duration; the :class:`CommandHandler` applies them and stops the motors when the
drive ends unless another drive command renewed it first (deadman). A drive ends at ``ts + duration_s`` on
the sender's clock (``clock``: the robot's clock corrected by the measured offset,
robot_agent/link/clock_sync.py) and never later than ``duration_s`` after its receipt, so a late renewal
cannot outlive its sender; one that arrives after its end is acked ``expired``. The motors get a lease of
the drive's remaining time plus ``watchdog_margin_s``, which a thread outside the loop enforces
(robot_agent/motors/watchdog.py). Every command is acked ``accepted`` then ``done`` (or ``rejected`` /
``expired``, final at once).
"""

from __future__ import annotations

import asyncio
import collections
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

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
from robot_agent.motors.watchdog import WATCHDOG_MARGIN_S
from robot_agent.util import RejectCounter

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Drive:
    """Wheel set-points (-1..1) to hold for ``duration_s`` (capped at the protocol's maximum)."""

    left: float
    right: float
    duration_s: float


class SelfAcked:
    """Returned by a handler that acks its command itself when it ends (a goal: robot_agent/motion)."""


SELF_ACKED = SelfAcked()


class MotionHooks(Protocol):
    """The motion runner (robot_agent/motion): drives pass its geofence first, and whatever stops or replaces
    a drive also ends its goal."""

    def check_drive(self, command_id: str, left: float, right: float, duration_s: float) -> str | None: ...

    def preempt(self, reason: str) -> None: ...


HandlerFn = Callable[[Any, "CommandHandler"], Drive | SelfAcked | None]


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
    watchdog_trips: int


class CommandHandler:
    """Runs on the asyncio loop; ``send_ack`` publishes an :class:`Ack` (QoS 1)."""

    def __init__(
        self,
        motors: MotorDriver,
        send_ack: Callable[[Ack], None],
        extra_commands: list[str] | None = None,
        on_state_change: Callable[[], None] | None = None,
        clock: Callable[[], float] = now,
        watchdog_margin_s: float | None = WATCHDOG_MARGIN_S,
        motion: MotionHooks | None = None,
    ) -> None:
        self.motors = motors
        self.motion = motion
        self.current_command_id = ""  # the command a handler is running for
        self._send_ack = send_ack
        self._on_state_change = on_state_change or (lambda: None)
        #: The sender's clock as read here: what ``ts`` and ``ttl_s`` are measured against.
        self._clock = clock
        self._watchdog_margin_s = watchdog_margin_s
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
            self._ack(cmd.id, AckStatus.EXPIRED, f"expired {at - cmd.ts - cmd.ttl_s:.3f}s ago (ttl {cmd.ttl_s}s)")
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
                f"{'.'.join(str(p) for p in e['loc']) or 'args'}: {e['msg']}" for e in exc.errors(include_url=False)
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
        self.current_command_id = cmd.id
        result = spec.handler(args, self)
        if isinstance(result, Drive):
            duration = min(max(result.duration_s, 0.0), MAX_DRIVE_DURATION_S)
            # ends at ts + duration on the sender's clock, and never later than duration from now
            remaining = min(duration, cmd.ts + duration - at)
            if remaining <= 0:
                self.rejects.reject("expired", f"{cmd.command} {cmd.id} (drive ended before it arrived)")
                self._ack(
                    cmd.id,
                    AckStatus.EXPIRED,
                    f"drive ended {-remaining:.3f}s before it arrived (ts + duration_s {duration}s)",
                )
                return
        self.executed.append(cmd.id)
        del self.executed[:-256]
        if isinstance(result, Drive):
            self._start_drive(cmd.id, result, remaining)
        elif isinstance(result, SelfAcked):
            pass
        elif cmd.command == CommandName.STOP:
            self._ack(cmd.id, AckStatus.ACCEPTED)
            self._preempt_motion("stopped")
            self._end_active("stopped")
            self._stop_motors()
            self._ack(cmd.id, AckStatus.DONE)
        else:
            self._ack(cmd.id, AckStatus.ACCEPTED)
            self._ack(cmd.id, AckStatus.DONE)

    # ------------------------------------------------------------------------------------------------
    def _start_drive(self, command_id: str, drive: Drive, remaining: float) -> None:
        if self.motion is not None:  # the geofence; an accepted drive ends a goal
            refusal = self.motion.check_drive(command_id, drive.left, drive.right, remaining)
            if refusal is not None:
                self._end_active(refusal.split(":")[0])
                self._ack(command_id, AckStatus.REJECTED, refusal)
                return
        lease = None if self._watchdog_margin_s is None else remaining + self._watchdog_margin_s
        try:
            self.motors.drive(drive.left, drive.right, lease)
        except Exception as exc:
            self._stop_motors()
            self._ack(command_id, AckStatus.REJECTED, f"motor error: {exc}")
            return
        self._ack(command_id, AckStatus.ACCEPTED)
        self._end_active("superseded", stop=False)
        loop = asyncio.get_running_loop()
        timer = loop.call_later(remaining, self._deadman, command_id)
        self._active = _ActiveDrive(command_id, timer, self.motors.watchdog.trips)

    def _deadman(self, command_id: str) -> None:
        active = self._active
        if active is None or active.command_id != command_id:
            return
        self._active = None
        self._stop_motors()
        tripped = self.motors.watchdog.trips != active.watchdog_trips
        self._ack(command_id, AckStatus.DONE, "motor watchdog" if tripped else "")

    def _end_active(self, reason: str, stop: bool = True) -> None:
        active, self._active = self._active, None
        if active is None:
            return
        active.timer.cancel()
        if stop:
            self._stop_motors()
        self._ack(active.command_id, AckStatus.DONE, reason)

    def _preempt_motion(self, reason: str) -> None:
        if self.motion is not None:
            try:
                self.motion.preempt(reason)
            except Exception:
                log.exception("ending the motion failed")

    def _stop_motors(self) -> None:
        try:
            self.motors.halt()
        except Exception:
            log.exception("motor stop failed")

    def stop_all(self, reason: str) -> None:
        """Stop now (link lost, shutdown); the running drive is acked done with ``reason``."""
        self._preempt_motion(reason)
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
            log.warning("E-STOP engaged (%s): drive commands refused until released", msg.reason or "no reason")
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
