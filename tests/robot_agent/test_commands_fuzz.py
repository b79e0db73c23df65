"""The robot agent's CommandHandler fuzzed with hostile ``cmd`` and ``fleet/estop`` payloads: nothing
escapes, bad commands are counted and never move the motors, the e-stop latch holds, a malformed e-stop
still stops the robot."""

from __future__ import annotations

import asyncio
import math
import time
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fleet_protocol import Ack, ProtocolError, decode_command
from robot_agent.commands import CommandHandler
from robot_agent.motors.base import MotorDriver
from tests.support.strategies import JSON, VALID, dump, mutated


class RecordingMotors(MotorDriver):
    def __init__(self) -> None:
        self.left = self.right = 0.0
        self.sets: list[tuple[float, float]] = []

    @classmethod
    def create(cls, config: Any, world: Any) -> RecordingMotors:
        return cls()

    def set(self, left: float, right: float) -> None:
        self.left, self.right = left, right
        self.sets.append((left, right))

    def stop(self) -> None:
        self.left = self.right = 0.0

    def operable(self) -> tuple[bool, str]:
        return True, ""

    @property
    def moving(self) -> bool:
        return self.left != 0.0 or self.right != 0.0


@st.composite
def command_payloads(draw: st.DrawFn) -> tuple[str, bytes]:
    fresh = {**VALID["command"], "ts": time.time() + 1.0}  # not expired while the example runs
    kind = draw(st.sampled_from(["valid", "mutated", "json", "bytes"]))
    if kind == "valid":
        cmd = {
            **fresh,
            "command": draw(st.sampled_from(["move_forward", "turn_left", "stop", "set_speed", "fly"])),
            "id": draw(st.text("abc123", min_size=1, max_size=6)),
        }
        return "cmd", dump(cmd)
    if kind == "mutated":
        return "cmd", dump(draw(mutated(fresh)))
    if kind == "json":
        return "cmd", dump(draw(JSON))
    return "cmd", draw(st.binary(max_size=100))


@st.composite
def estop_payloads(draw: st.DrawFn) -> tuple[str, bytes]:
    kind = draw(st.sampled_from(["engage", "release", "mutated", "bytes"]))
    if kind in ("engage", "release"):
        return "estop", dump({**VALID["estop"], "engaged": kind == "engage", "id": draw(st.sampled_from(["e1", "e2"]))})
    if kind == "mutated":
        return "estop", dump(draw(mutated(VALID["estop"])))
    return "estop", draw(st.binary(max_size=60))


def _decodes(payload: bytes) -> bool:
    try:
        decode_command(payload)
    except ProtocolError:
        return False
    return True


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(command_payloads() | estop_payloads(), min_size=1, max_size=12))
def test_command_handler_survives_anything(messages):
    async def body() -> None:
        motors = RecordingMotors()
        acks: list[Ack] = []
        h = CommandHandler(motors, acks.append, extra_commands=["set_speed"])
        for topic, payload in messages:
            before_rejects, before_executed, before_moving = h.rejects.total, list(h.executed), motors.moving
            n_sets = len(motors.sets)
            if topic == "cmd":
                h.handle_payload(payload)  # must not raise
                if not _decodes(payload):
                    assert h.rejects.total == before_rejects + 1
                    assert h.executed == before_executed and motors.moving == before_moving
                    assert len(motors.sets) == n_sets
            else:
                h.handle_estop_payload(payload)
                if h.rejects.total > before_rejects:
                    assert not motors.moving  # a malformed e-stop still stops the robot
            if h.estop_engaged:
                assert not motors.moving
            for left, right in motors.sets:
                assert math.isfinite(left) and math.isfinite(right) and abs(left) <= 1 and abs(right) <= 1
        assert all(not a.reason.startswith("internal error") for a in acks), [a.reason for a in acks]
        assert all(isinstance(a, Ack) and len(a.reason) <= 500 for a in acks)
        h.stop_all("end of example")
        assert not motors.moving

    asyncio.run(body())


def test_bad_commands_are_counted_and_logged_at_a_limited_rate(caplog):
    caplog.set_level("WARNING")
    motors = RecordingMotors()
    h = CommandHandler(motors, lambda ack: None)
    for i in range(200):
        h.handle_payload(b"\xff not json %d" % i)
    assert h.rejects.counts["bad_json"] == 200 and not motors.sets
    assert 1 <= len([r for r in caplog.records if "rejected" in r.getMessage()]) <= 2
