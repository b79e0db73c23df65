"""Command handler: validation, expiry, gate, deadman, supersede, e-stop latch (real asyncio loop, fake motors)."""

from __future__ import annotations

import asyncio
import functools
import time
from collections.abc import Awaitable, Callable
from typing import Any

import orjson
import pytest

from fleet_protocol import MAX_DRIVE_DURATION_S, Ack, Command, EStop, dumps, new_command
from robot_agent.commands import COMMAND_REGISTRY, CommandHandler, CommandSpec, Drive, register_command
from robot_agent.motors.base import MotorDriver
from tests.support.procs import wait_until


class RecordingMotors(MotorDriver):
    def __init__(self) -> None:
        self.calls: list[tuple[str, float, float, float]] = []
        self.left = self.right = 0.0
        self.fault: str | None = None

    @classmethod
    def create(cls, config: Any, world: Any) -> RecordingMotors:
        return cls()

    def set(self, left: float, right: float) -> None:
        self.left, self.right = left, right
        self.calls.append(("set", left, right, time.monotonic()))

    def stop(self) -> None:
        self.left = self.right = 0.0
        self.calls.append(("stop", 0.0, 0.0, time.monotonic()))

    def operable(self) -> tuple[bool, str]:
        return (False, self.fault) if self.fault else (True, "")

    @property
    def moving(self) -> bool:
        return self.left != 0.0 or self.right != 0.0


class Rig:
    def __init__(self, extra: list[str] | None = None) -> None:
        self.motors = RecordingMotors()
        self.acks: list[Ack] = []
        self.state_changes = 0
        self.handler = CommandHandler(self.motors, self.acks.append, extra, on_state_change=self._changed)

    def _changed(self) -> None:
        self.state_changes += 1

    def send(self, command: str, args: dict[str, Any] | None = None, **kw: Any) -> str:
        cmd = new_command(command, args)
        if kw:
            cmd = Command.model_validate({**cmd.model_dump(), **kw})
        self.handler.handle_payload(dumps(cmd))
        return cmd.id

    def statuses(self, cid: str) -> list[tuple[str, str]]:
        return [(a.status.value, a.reason) for a in self.acks if a.id == cid]


def run(fn: Callable[[Rig], Awaitable[None]], extra: list[str] | None = None) -> Rig:
    rig = Rig(extra)
    asyncio.run(fn(rig))
    return rig


until = functools.partial(wait_until, timeout=3.0, interval=0.005)


def test_drive_is_accepted_then_done_after_duration_and_stops_motors() -> None:
    async def body(r: Rig) -> None:
        t0 = time.monotonic()
        cid = r.send("move_forward", {"speed": 0.8, "duration_s": 0.2})
        assert r.statuses(cid) == [("accepted", "")]
        assert (r.motors.left, r.motors.right) == (0.8, 0.8)
        await until(lambda: len(r.statuses(cid)) == 2)
        elapsed = time.monotonic() - t0
        assert r.statuses(cid)[-1] == ("done", "")
        assert not r.motors.moving
        assert 0.18 <= elapsed < 0.6

    run(body)


@pytest.mark.parametrize(
    ("command", "left", "right"),
    [("move_forward", 0.5, 0.5), ("move_backward", -0.5, -0.5), ("turn_left", -0.5, 0.5), ("turn_right", 0.5, -0.5)],
)
def test_drive_directions_and_default_speed(command: str, left: float, right: float) -> None:
    async def body(r: Rig) -> None:
        r.send(command, {"duration_s": 0.05})
        assert (r.motors.left, r.motors.right) == (left, right)
        await until(lambda: not r.motors.moving)

    run(body)


def test_default_duration_is_half_a_second() -> None:
    async def body(r: Rig) -> None:
        t0 = time.monotonic()
        cid = r.send("move_forward")
        # done at the deadline; on a loaded machine the motor watchdog (deadline + 0.15 s, its own thread) may
        # end it first, reason "motor watchdog": either way the drive lasted the default half second
        await until(lambda: any(status == "done" for status, _ in r.statuses(cid)), timeout=3)
        assert 0.45 <= time.monotonic() - t0 < 1.0
        assert next(reason for status, reason in r.statuses(cid) if status == "done") in ("", "motor watchdog")

    run(body)


def test_renewal_supersedes_and_extends_the_deadman() -> None:
    async def body(r: Rig) -> None:
        first = r.send("move_forward", {"duration_s": 0.3})
        await asyncio.sleep(0.2)  # the renewal comes 0.2 s into the first drive: the timing under test
        t1 = time.monotonic()
        second = r.send("turn_left", {"duration_s": 0.3})
        assert r.statuses(first) == [("accepted", ""), ("done", "superseded")]
        # the robot is still driving past the first command's deadline (0.4 s after it: the instant under test)
        await asyncio.sleep(0.2)
        assert r.motors.moving
        await until(lambda: ("done", "") in r.statuses(second))
        assert time.monotonic() - t1 >= 0.28
        assert not r.motors.moving

    run(body)


def test_stop_ends_the_drive_at_once() -> None:
    async def body(r: Rig) -> None:
        drive = r.send("move_forward", {"duration_s": 5})
        stop = r.send("stop")
        assert not r.motors.moving
        assert r.statuses(drive) == [("accepted", ""), ("done", "stopped")]
        assert r.statuses(stop) == [("accepted", ""), ("done", "")]

    run(body)


def test_expired_command_is_acked_expired_and_never_executed() -> None:
    async def body(r: Rig) -> None:
        cid = r.send("move_forward", {"speed": 1.0}, ts=time.time() - 5.0, ttl_s=2.0)
        assert [s for s, _ in r.statuses(cid)] == ["expired"]
        assert "expired" in r.statuses(cid)[0][1]
        assert r.motors.calls == []
        assert cid not in r.handler.executed

    run(body)


def test_unknown_command_is_rejected_with_reason() -> None:
    async def body(r: Rig) -> None:
        cid = r.send("fly_away")
        assert r.statuses(cid) == [("rejected", "unknown command 'fly_away'")]
        assert r.handler.rejects.counts["unknown_command"] == 1

    run(body)


@pytest.mark.parametrize(
    ("args", "field"),
    [
        ({"speed": 1.5}, "speed"),
        ({"speed": "fast"}, "speed"),
        ({"duration_s": 0}, "duration_s"),
        ({"duration_s": 10}, "duration_s"),
        ({"bogus": 1}, "bogus"),
    ],
)
def test_bad_args_are_rejected_with_reason(args: dict[str, Any], field: str) -> None:
    async def body(r: Rig) -> None:
        cid = r.send("move_forward", args)
        ((status, reason),) = r.statuses(cid)
        assert status == "rejected"
        assert reason.startswith("bad args") and field in reason
        assert r.motors.calls == []

    run(body)


def test_drive_duration_is_capped_at_five_seconds_even_for_custom_handlers() -> None:
    register_command(
        CommandSpec(
            "creep_test", COMMAND_REGISTRY["stop"].args_model, lambda args, h: Drive(0.1, 0.1, 60.0), drives=True
        )
    )

    async def body(r: Rig) -> None:
        loop = asyncio.get_running_loop()
        cid = r.send("creep_test")
        assert r.motors.moving
        active = r.handler._active
        assert active is not None
        assert active.timer.when() - loop.time() <= MAX_DRIVE_DURATION_S + 0.01
        r.send("stop")
        assert ("done", "stopped") in r.statuses(cid)

    try:
        run(body, extra=["creep_test"])
    finally:
        COMMAND_REGISTRY.pop("creep_test")


def test_motor_gate_rejects_drives_but_stop_is_always_allowed() -> None:
    async def body(r: Rig) -> None:
        r.motors.fault = "overcurrent"
        cid = r.send("move_forward")
        assert r.statuses(cid) == [("rejected", "motor not operable: overcurrent")]
        assert not any(c[0] == "set" for c in r.motors.calls)
        stop = r.send("stop")
        assert r.statuses(stop) == [("accepted", ""), ("done", "")]
        r.motors.fault = None
        ok = r.send("move_forward", {"duration_s": 0.05})
        assert r.statuses(ok)[0] == ("accepted", "")

    run(body)


def test_extension_set_speed_changes_the_default_speed() -> None:
    async def body(r: Rig) -> None:
        assert "set_speed" in r.handler.command_names
        cid = r.send("set_speed", {"speed": 0.25})
        assert r.statuses(cid) == [("accepted", ""), ("done", "")]
        r.send("move_forward", {"duration_s": 0.05})
        assert r.motors.left == 0.25
        r.send("move_forward", {"speed": 0.9, "duration_s": 0.05})
        assert r.motors.left == 0.9

    run(body, extra=["set_speed"])


def test_extension_not_enabled_is_unknown() -> None:
    async def body(r: Rig) -> None:
        assert "set_speed" not in r.handler.command_names
        cid = r.send("set_speed", {"speed": 0.25})
        assert r.statuses(cid)[0][0] == "rejected"

    run(body)


def test_unknown_extra_command_in_config_is_an_error() -> None:
    with pytest.raises(ValueError, match="unknown command handler"):
        CommandHandler(RecordingMotors(), lambda a: None, ["no_such_cmd"])


def test_estop_stops_latches_and_release_unlatches() -> None:
    async def body(r: Rig) -> None:
        drive = r.send("move_forward", {"duration_s": 5})
        r.handler.handle_estop_payload(dumps(EStop(ts=time.time(), id="es-1", reason="test")))
        assert not r.motors.moving
        assert r.statuses(drive)[-1] == ("done", "e-stop")
        assert r.statuses("es-1") == [("done", "stopped")]
        assert r.handler.estop_engaged and r.state_changes == 1
        refused = r.send("move_forward")
        assert r.statuses(refused) == [("rejected", "e-stop engaged")]
        stop = r.send("stop")
        assert r.statuses(stop)[-1] == ("done", "")
        # the retained e-stop redelivered (reconnect) does not ack twice, still latched
        r.handler.handle_estop_payload(dumps(EStop(ts=time.time(), id="es-1")))
        assert r.statuses("es-1") == [("done", "stopped")]
        r.handler.handle_estop_payload(dumps(EStop(ts=time.time(), id="rel-1", engaged=False)))
        assert not r.handler.estop_engaged
        assert r.statuses("rel-1") == [("done", "released")]
        ok = r.send("move_forward", {"duration_s": 0.05})
        assert r.statuses(ok)[0] == ("accepted", "")

    run(body)


def test_empty_retained_estop_is_a_release() -> None:
    async def body(r: Rig) -> None:
        r.handler.handle_estop(EStop(ts=time.time(), id="e"))
        r.handler.handle_estop_payload(b"")
        assert not r.handler.estop_engaged

    run(body)


def test_malformed_messages_are_counted_and_handler_keeps_working() -> None:
    async def body(r: Rig) -> None:
        for junk in (b"", b"not json", b"[1,2]", b'{"id": "x"}', b"\xff\xfe", orjson.dumps({"command": 5})):
            r.handler.handle_payload(junk)
        r.handler.handle_estop_payload(b"{nope")
        assert r.handler.rejects.total == 7
        assert not r.handler.estop_engaged  # a malformed e-stop stops but does not latch
        # a bad command that still carries an id is rejected so the sender is not left waiting
        assert r.statuses("x") and r.statuses("x")[0][0] == "rejected"
        cid = r.send("move_forward", {"duration_s": 0.05})
        assert r.statuses(cid)[0] == ("accepted", "")

    run(body)


def test_duplicate_delivery_is_executed_once() -> None:
    async def body(r: Rig) -> None:
        cmd = new_command("move_forward", {"duration_s": 0.05})
        r.handler.handle_payload(dumps(cmd))
        r.handler.handle_payload(dumps(cmd))
        assert [s for s, _ in r.statuses(cmd.id)] == ["accepted"]
        assert r.handler.executed.count(cmd.id) == 1

    run(body)


def test_link_loss_stops_the_drive() -> None:
    async def body(r: Rig) -> None:
        cid = r.send("move_forward", {"duration_s": 5})
        r.handler.stop_all("link lost")
        assert not r.motors.moving
        assert r.statuses(cid)[-1] == ("done", "link lost")

    run(body)


def test_motor_error_rejects_and_stops() -> None:
    class Broken(RecordingMotors):
        def set(self, left: float, right: float) -> None:
            raise OSError("i2c gone")

    async def body(r: Rig) -> None:
        r.handler.motors = Broken()
        cid = r.send("move_forward")
        assert r.statuses(cid) == [("rejected", "motor error: i2c gone")]

    run(body)
