"""The motor watchdog: a thread outside the agent's event loop zeroes the motors when the loop has not
refreshed them within duration_s + 0.2 s. Measured on a real agent process whose loop is frozen for 2 s
(debug hook, SIGUSR1) while it drives: from the simulated motor driver's set-point trace (written by the
thread that applied each set-point, when it did) and from the robot's position telemetry."""

from __future__ import annotations

import json
import signal
import threading
import time
from pathlib import Path
from typing import Any

import orjson
import pytest

from fleet_protocol import Topics
from robot_agent.motors.base import MotorDriver
from robot_agent.motors.watchdog import WATCHDOG_MARGIN_S, MotorWatchdog
from tests.robot_agent.test_agent_integration import j, send, wait_ack, wait_online
from tests.support.acl_fleet import AclFleet, acl_fleet
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, wait_for

pytestmark = pytest.mark.realtime  # wall-clock safety bounds: the realtime lane, alone (docs/testing.md)

T = Topics()
#: the promise: motors zeroed within the drive's duration_s + this of the loop's last refresh
BOUND_S = 0.2
SPEED_MPS = 0.3  # the simulated robot's speed at command speed 1.0 (--max-speed default)


class ThreadRecordingMotors(MotorDriver):
    def __init__(self) -> None:
        self.calls: list[tuple[str, float, str]] = []

    @classmethod
    def create(cls, config: Any, world: Any) -> ThreadRecordingMotors:
        return cls()

    def set(self, left: float, right: float) -> None:
        self.calls.append(("set", time.monotonic(), threading.current_thread().name))

    def stop(self) -> None:
        self.calls.append(("stop", time.monotonic(), threading.current_thread().name))

    def operable(self) -> tuple[bool, str]:
        return True, ""


def test_watchdog_zeroes_unrefreshed_motors_from_its_own_thread_and_spares_refreshed_ones() -> None:
    m = ThreadRecordingMotors()
    try:
        # refreshed every 0.1 s with a 0.3 s lease for 1 s: the watchdog must never cut in
        for _ in range(10):
            refreshed = time.monotonic()  # the lease starts inside drive(), before the set-point is recorded
            m.drive(0.5, 0.5, lease_s=0.3)
            time.sleep(0.1)  # the refresh cadence under test (a driver renewing its lease), not a wait
        assert [c[0] for c in m.calls] == ["set"] * 10 and m.watchdog.trips == 0
        last = m.calls[-1][1]
        wait_for(lambda: m.watchdog.trips == 1, 2, 0.01, "watchdog trip")
        kind, at, thread = m.calls[-1]
        assert (kind, thread) == ("stop", "motor-watchdog")
        # not before the lease's end (counted from the last refresh, not from the set-point recorded after
        # it: once, that was 0.29998 s); the thread's wake-up may take what the promise leaves beyond the margin
        assert at - refreshed >= 0.3
        assert at - last <= 0.3 + (BOUND_S - WATCHDOG_MARGIN_S)
        # and again after a halt: the watchdog keeps watching every new lease
        m.halt()
        m.drive(0.5, 0.5, lease_s=0.1)
        wait_for(lambda: m.watchdog.trips == 2, 2, 0.01, "second trip")
        assert [(c[0], c[2]) for c in m.calls[-3:]] == [
            ("stop", "MainThread"),
            ("set", "MainThread"),
            ("stop", "motor-watchdog"),
        ]
    finally:
        m.shutdown()


def test_watchdog_survives_a_failing_stop_and_keeps_watching() -> None:
    calls: list[str] = []

    def bad_stop() -> None:
        calls.append("stop")
        raise RuntimeError("gpio gone")

    wd = MotorWatchdog(bad_stop)
    try:
        with wd.lock:
            wd.arm(0.05)
        wait_for(lambda: wd.trips == 1, 2, 0.01)
        with wd.lock:
            wd.arm(0.05)
        wait_for(lambda: wd.trips == 2, 2, 0.01)
        assert calls == ["stop", "stop"]
    finally:
        wd.close()


def _trace(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _x(probe: MqttProbe, rid: str, after: float) -> float:
    m = probe.wait(lambda m: m.topic == T.telemetry(rid, "position") and j(m)["ts"] > after, 10)
    return float(j(m)["data"]["x"])


@pytest.mark.parametrize("watchdog", [True, False], ids=["watchdog", "without-watchdog"])
def test_frozen_event_loop_motors_zeroed_within_duration_plus_0_2_s(
    watchdog: bool, workdir: Path, tmp_path: Path
) -> None:
    """A drive of 1 s, then the agent's loop is frozen for 2 s: with the watchdog the motors are zeroed by
    the watchdog thread within 1.2 s of the set-point; without it (debug switch) they stay on for the whole
    freeze, which is what the measurement must catch. The shipped broker, authentication and ACL on."""
    with acl_fleet(workdir) as fleet:
        _frozen_loop(fleet, watchdog, tmp_path)


def _frozen_loop(fleet: AclFleet, watchdog: bool, tmp_path: Path) -> None:
    rid = "robot-1"
    trace = tmp_path / "motors.jsonl"
    env = {
        "FLEET_AGENT_DEBUG_HOOKS": "1",
        "FLEET_AGENT_DEBUG_FREEZE_S": "2",
        "FLEET_AGENT_MOTORS": orjson.dumps({"type": "sim", "trace_file": str(trace)}).decode(),
    }
    if not watchdog:
        env["FLEET_AGENT_DEBUG_NO_MOTOR_WATCHDOG"] = "1"
    probe = fleet.probe(T.ack(rid), T.status(rid), T.telemetry(rid, "position"))
    agent = fleet.agent(rid, "--start-pose", "0,0,0", "--position-rate", "50", **env)
    agent.start()
    try:
        _drive_and_freeze(agent, probe, rid, trace, watchdog)
    finally:
        agent.stop()
        probe.close()


def _drive_and_freeze(agent: AgentProcess, probe: MqttProbe, rid: str, trace: Path, watchdog: bool) -> None:
    wait_online(probe, rid)
    x0 = _x(probe, rid, time.time())
    duration = 1.0
    ts = time.time()
    cid = send(probe, rid, "move_forward", {"speed": 1.0, "duration_s": duration}, ts=ts)
    wait_ack(probe, rid, cid, "accepted", 5)
    assert agent.proc is not None
    agent.proc.send_signal(signal.SIGUSR1)  # the loop freezes for 2 s from here
    done = wait_ack(probe, rid, cid, "done", 10)
    wait_for(lambda: "event loop running again" in agent.output(), 10, what="end of the freeze")
    x1 = _x(probe, rid, time.time() + 0.3)  # the wheels have settled

    rows = _trace(trace)
    (first_on,) = [i for i, r in enumerate(rows) if r["left"] != 0.0]
    refresh = rows[first_on]
    zero = rows[first_on + 1]
    assert zero["left"] == zero["right"] == 0.0
    on_for = zero["t"] - refresh["t"]
    travelled = x1 - x0
    log = agent.output()
    assert "DEBUG: freezing the event loop for 2.00 s" in log
    if watchdog:
        assert zero["thread"] == "motor-watchdog", rows
        assert done["reason"] == "motor watchdog"
        # the lease ends at ts + duration + WATCHDOG_MARGIN_S (never before the drive's own end); the bound
        # leaves the rest for the thread's wake-up
        assert zero["t"] >= ts + duration + WATCHDOG_MARGIN_S
        assert on_for <= duration + BOUND_S, on_for
        # the robot itself: it moved for at most duration + 0.2 s at full speed
        assert SPEED_MPS * duration * 0.9 < travelled <= SPEED_MPS * (duration + BOUND_S), travelled
    else:
        # nothing zeroed them until the loop ran again, 2 s after the freeze began
        assert zero["thread"] == "MainThread", rows
        assert on_for > 1.9, on_for
        assert travelled > SPEED_MPS * 1.9, travelled


def test_watchdog_zeroes_the_gpio_driver_pins() -> None:
    """Every driver gets the watchdog from the base class: the H-bridge's PWM pins (gpiozero mock pins, the
    only mocked part) go to 0 from the watchdog's thread."""
    gpiozero = pytest.importorskip("gpiozero")
    from gpiozero.pins.mock import MockFactory, MockPWMPin

    from robot_agent.motors import create_motor_driver

    factory = MockFactory(pin_class=MockPWMPin)
    gpiozero.Device.pin_factory = factory
    pins = {"left_forward": 17, "left_backward": 18, "right_forward": 22, "right_backward": 23}
    d = create_motor_driver({"type": "gpio", **pins}, None)
    try:
        d.drive(0.6, -0.4, lease_s=0.1)
        assert factory.pin(17).state == pytest.approx(0.6) and factory.pin(23).state == pytest.approx(0.4)
        wait_for(lambda: d.watchdog.trips == 1, 2, 0.01, "watchdog trip")
        assert all(factory.pin(n).state == 0 for n in pins.values())
        assert d.operable() == (True, "")  # a trip is not a fault: the next drive runs
    finally:
        d.shutdown()
        factory.reset()
        gpiozero.Device.pin_factory = None
