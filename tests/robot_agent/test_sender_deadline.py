"""A deadman counts from the sender's clock, never from the receipt: the shipped broker with authentication
and the shipped ACL, a real fleet server (which answers the clock sync) and real simulated agents, each
logged in with its own account. A renewal delivered 0.8 s late does not extend the motion past its
ts + duration_s, measured from the simulated motor driver's set-point trace and the robot's position
telemetry; a proper renewal chain still drives without a gap; a robot whose wall clock is 5 s off drives by
the measured offset."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import orjson
import pytest

from fleet_protocol import AvoidanceSettings, Topics
from robot_agent.motors.watchdog import WATCHDOG_MARGIN_S
from tests.robot_agent.test_agent_integration import j, send, wait_ack
from tests.support.acl_fleet import AclFleet, acl_fleet
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, ManagedProcess, ServerProcess, wait_for
from tests.support.proxy import FreezableProxy

pytestmark = pytest.mark.realtime  # wall-clock safety bounds: the realtime lane, alone (docs/testing.md)

T = Topics()
#: How late the loop's deadman may stop a drive after its ts + duration_s: the asyncio timer's latency, up to
#: the motor watchdog's margin (a loop later than that is stalled, and the watchdog thread stops the motors).
#: Measured on a 2-core machine at load 7: 1-29 ms.
TIMER_LATENCY_S = WATCHDOG_MARGIN_S
#: the site's default creep speed (fleet_protocol AvoidanceSettings) as a fraction of the sim's 0.3 m/s wheels
CREEP_FRACTION = round(AvoidanceSettings().creep_mps / 0.3, 6)


class Fleet:
    """The ACL'd broker plus the processes a test starts (all stopped at the end)."""

    def __init__(self, acl: AclFleet, database_url: str, tmp_path: Path) -> None:
        self.acl = acl
        self.database_url = database_url
        self.tmp_path = tmp_path
        self.procs: list[ManagedProcess] = []
        self.probes: list[MqttProbe] = []

    def server(self) -> ServerProcess:
        s = self.acl.server(self.database_url)
        self.procs.append(s)
        s.start()
        return s

    def robot(self, rid: str, broker_url: str | None = None, **env: str) -> TracedRobot:
        probe = self.acl.probe(T.ack(rid), T.status(rid), T.telemetry(rid, "position"))
        self.probes.append(probe)
        trace = self.tmp_path / f"{rid}-motors.jsonl"
        motors = orjson.dumps({"type": "sim", "trace_file": str(trace)}).decode()
        agent = self.acl.agent(
            rid,
            "--start-pose",
            "0,0,0",
            "--position-rate",
            "50",
            broker_url=broker_url,
            FLEET_AGENT_MOTORS=motors,
            **env,
        )
        self.procs.append(agent)
        agent.start()
        return TracedRobot(rid, agent, probe, trace)


@pytest.fixture
def fleet(workdir: Path, database_url: str, tmp_path: Path) -> Iterator[Fleet]:
    with acl_fleet(workdir) as acl:
        f = Fleet(acl, database_url, tmp_path)
        try:
            yield f
        finally:
            for proc in reversed(f.procs):
                proc.stop()
            for probe in f.probes:
                probe.close()


class TracedRobot:
    def __init__(self, rid: str, agent: AgentProcess, probe: MqttProbe, trace: Path) -> None:
        self.rid = rid
        self.agent = agent
        self.probe = probe
        self.trace = trace

    def rows(self) -> list[dict[str, Any]]:
        if not self.trace.exists():
            return []
        return [json.loads(line) for line in self.trace.read_text().splitlines() if line.strip()]

    def status(self, pred: Callable[[dict[str, Any]], bool], timeout: float = 20) -> dict[str, Any]:
        m = self.probe.wait(lambda m: m.topic == T.status(self.rid) and pred(j(m)), timeout)
        return dict(j(m))

    def x(self, after: float) -> float:
        m = self.probe.wait(lambda m: m.topic == T.telemetry(self.rid, "position") and j(m)["ts"] > after, 10)
        return float(j(m)["data"]["x"])

    def drive(self, ts: float, duration: float) -> str:
        return send(self.probe, self.rid, "move_forward", {"speed": 1.0, "duration_s": duration}, ts=ts)


def test_a_renewal_delayed_by_0_8_s_does_not_extend_the_motion_past_its_ts_plus_duration(fleet: Fleet) -> None:
    fleet.server()
    robot = fleet.robot("robot-1")
    st = robot.status(lambda s: s.get("clock_synced") is True)
    assert abs(st["clock_offset_ms"]) < 50 and 0 <= st["clock_rtt_ms"] < 100  # one machine, one clock

    # 1. the last renewal of a client that died, delivered 0.8 s after it was sent: 0.5 s to run -> expired
    x0 = robot.x(time.time())
    late = robot.drive(time.time() - 0.8, 0.5)
    ack = wait_ack(robot.probe, robot.rid, late, "expired")
    assert "before it arrived" in ack["reason"]
    assert robot.x(time.time() + 0.3) == x0  # it never moved ...
    assert robot.rows() == []  # ... and the motors never got a set-point

    # 2. the same delay with 1.0 s to run: it moves for what is left of the 1.0 s (0.2 s), not 1.0 s
    ts = time.time() - 0.8
    cid = robot.drive(ts, 1.0)
    wait_ack(robot.probe, robot.rid, cid, "done")
    on, off = robot.rows()
    assert on["left"] == 1.0 and off["left"] == 0.0
    assert off["t"] <= ts + 1.0 + TIMER_LATENCY_S, off["t"] - (ts + 1.0)
    assert 0.1 < off["t"] - on["t"] < 0.25  # 0.2 s minus the delivery time
    x1 = robot.x(time.time() + 0.3)
    assert 0.3 * 0.1 < x1 - x0 < 0.3 * 0.25  # and the robot travelled accordingly (0.3 m/s)

    # 3. a proper renewal chain (every 0.1 s, 0.5 s each) drives without a gap and ends 0.5 s after the last
    before = len(robot.rows())
    last_ts = 0.0
    for _ in range(20):
        last_ts = time.time()
        cid = robot.drive(last_ts, 0.5)
        time.sleep(0.1)  # the renewal cadence under test, not a wait
    wait_ack(robot.probe, robot.rid, cid, "done")
    chain = robot.rows()[before:]
    assert [r["left"] for r in chain] == [1.0] * 20 + [0.0], chain  # never zeroed in between
    assert chain[-1]["t"] <= last_ts + 0.5 + TIMER_LATENCY_S
    assert chain[-1]["t"] - chain[0]["t"] > 2.3  # moved for the whole chain: the check did not cut it short


def test_drives_held_up_0_8_s_in_the_network_end_at_their_ts_plus_duration(fleet: Fleet) -> None:
    """A real delivery delay: the robot's link to the broker is held (a frozen TCP proxy) while two drives
    are sent, then released 0.8 s later. The 0.5 s drive is acked expired and never moves the motors; the
    1.0 s drive runs for what is left of it and stops at its ts + duration_s, not 1.0 s after delivery."""
    fleet.server()
    proxy = FreezableProxy("127.0.0.1", fleet.acl.port)
    robot = fleet.robot("robot-2", broker_url=proxy.url)
    probe = robot.probe
    try:
        robot.status(lambda s: s.get("clock_synced") is True)
        proxy.freeze()
        ts = time.time()
        short = robot.drive(ts, 0.5)
        long = robot.drive(ts, 1.0)
        time.sleep(0.8)  # the delay under test: the commands wait in the network
        proxy.thaw()
        assert "before it arrived" in wait_ack(probe, robot.rid, short, "expired")["reason"]
        accepted = wait_ack(probe, robot.rid, long, "accepted")
        wait_ack(probe, robot.rid, long, "done")
        rows = robot.rows()
        on, off = rows[0], rows[-1]
        # The frozen link also held the fleet's poses: the robot knew nothing fresh of its neighbours and may
        # creep (the site's 0.03 m/s: 0.1 of full speed) until the next poses message (docs/safety.md).
        speeds = {round(r["left"], 6) for r in rows[:-1]}
        assert speeds <= {1.0, CREEP_FRACTION} and off["left"] == 0.0, rows
        assert on["t"] >= ts + 0.8 and accepted["ts"] >= ts + 0.8  # it really arrived 0.8 s late
        assert off["t"] <= ts + 1.0 + TIMER_LATENCY_S, off["t"] - (ts + 1.0)
    finally:
        robot.agent.stop()  # before the proxy goes
        proxy.close()


def test_a_robot_with_a_wrong_wall_clock_drives_by_the_measured_offset(fleet: Fleet) -> None:
    """The robot's wall clock runs 5 s ahead (debug hook). With no server to measure against, every command
    looks 5 s old and expires (ttl 2 s): the check can fail. Once the server answers the clock sync the
    offset is measured (-5000 ms) and the same commands run and end at their ts + duration_s."""
    robot = fleet.robot("robot-3", FLEET_AGENT_DEBUG_HOOKS="1", FLEET_AGENT_DEBUG_CLOCK_SKEW_S="5")
    st = robot.status(lambda s: s["online"] is True)
    assert st["clock_synced"] is False and st["clock_offset_ms"] is None
    cid = robot.drive(time.time(), 0.5)
    assert "expired" in wait_ack(robot.probe, robot.rid, cid, "expired")["reason"]
    assert robot.rows() == []

    fleet.server()
    st = robot.status(lambda s: s.get("clock_synced") is True, timeout=30)
    assert abs(st["clock_offset_ms"] + 5000) < 50, st
    ts = time.time()
    cid = robot.drive(ts, 0.5)
    wait_ack(robot.probe, robot.rid, cid, "done")
    on, off = robot.rows()
    assert on["left"] == 1.0 and off["left"] == 0.0
    # the trace is written with the machine's true clock (the skew is the agent's view only)
    assert ts + 0.5 - 0.05 < off["t"] <= ts + 0.5 + TIMER_LATENCY_S
    late = robot.drive(time.time() - 0.8, 0.5)
    wait_ack(robot.probe, robot.rid, late, "expired")
    wait_for(lambda: "clock synced with the server" in robot.agent.output(), 5)
