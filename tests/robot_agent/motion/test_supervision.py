"""A goal stops, within 0.5 s, on every way it can lose its footing: the position fix, the link, the server's
heartbeat (1 s of silence first), the e-stop, a stop, another motion command. "Stopped" is measured from the
wheel set-points the agent reports on its motion stream; each case first shows the wheels were turning."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from fleet_protocol import HEARTBEAT_SILENCE_S, default_pool_site
from tests.support.motion import DISTURBED, FakeServer, first_stop_after, moving_at
from tests.support.procs import VENV_BIN, Broker, ManagedProcess, base_env, wait_for
from tests.support.proxy import FreezableProxy

pytestmark = pytest.mark.realtime  # wall-clock safety bounds: the realtime lane, alone (docs/testing.md)

STOP_BOUND_S = 0.5
RID = "sup-1"


@pytest.fixture
def proxy(broker: Broker) -> Iterator[FreezableProxy]:
    p = FreezableProxy(broker.host, broker.port)
    try:
        yield p
    finally:
        p.close()


@pytest.fixture
def robot(proxy: FreezableProxy, fake_server: FakeServer, workdir: Path) -> Iterator[ManagedProcess]:
    """A disturbed simulated robot behind a freezable link, supervised by the fake server, on a long goal."""
    fake_server.publish_site(1, default_pool_site())
    fake_server.start_heartbeat()
    agent = ManagedProcess(
        f"agent-{RID}",
        [
            str(VENV_BIN / "fleet-agent"),
            "--robot-id",
            RID,
            "--simulate",
            "--broker",
            proxy.url,
            "--start-pose=-1.4,0,0",
            *DISTURBED,
        ],
        base_env(),
        workdir,
    )
    agent.start()
    try:
        fake_server.wait_online(RID)
        yield agent
    finally:
        agent.stop()


def start_goal(srv: FakeServer) -> str:
    cid = srv.send(RID, "goto", {"x": 1.4, "y": 0.2, "max_speed": 0.15})
    accepted = srv.ack(RID, cid, "accepted")
    # under way: a report with the wheels turning, a second after the start
    srv.wait_motion(
        RID, cid, lambda e: e["ts"] > accepted["ts"] + 1.0 and abs(e["data"]["setpoint"]["linear"]) > 0.05, 10
    )
    return cid


def assert_stopped(srv: FakeServer, cid: str, since: float, bound: float) -> float:
    wait_for(lambda: first_stop_after(srv.motion(RID, cid), since), 10, what="a stopped motion report")
    reports = srv.motion(RID, cid)
    assert moving_at(reports, since), "the wheels were not turning when the fault came: nothing to prove"
    stopped = first_stop_after(reports, since)
    assert stopped is not None
    assert stopped - since <= bound, f"stopped {stopped - since:.3f} s after the fault (bound {bound} s)"
    print(f"stopped {stopped - since:.3f} s after the fault (bound {bound} s)")
    return stopped - since


def test_lost_position_fix_stops_the_goal(robot: ManagedProcess, fake_server: FakeServer) -> None:
    srv = fake_server
    cid = start_goal(srv)
    assert robot.proc is not None
    robot.proc.send_signal(signal.SIGUSR2)  # the simulated Lighthouse goes dark
    final = srv.final_ack(RID, cid, 10)
    assert final["status"] == "failed" and final["reason"].startswith("no_position"), final
    last_fix = max(e["ts"] for e in srv.stream(RID, "position") if e["ts"] <= final["ts"])
    assert_stopped(srv, cid, last_fix, STOP_BOUND_S)


def test_lost_link_stops_the_goal_and_reports_after(
    robot: ManagedProcess, fake_server: FakeServer, proxy: FreezableProxy
) -> None:
    srv = fake_server
    cid = start_goal(srv)
    frozen_at = time.time()
    proxy.freeze()
    time.sleep(1.5)  # the outage itself: the robot must stop on its own, hearing nothing
    assert not [
        a
        for a in srv.probe.matching(lambda m: m.topic.endswith("/ack"))
        if cid.encode() in a.payload and b'"failed"' in a.payload
    ], "an ack came through a frozen link"
    proxy.thaw()
    final = srv.final_ack(RID, cid, 30)  # reported once the link is back, never resumed silently
    assert final["status"] == "failed" and final["reason"].startswith("link_lost"), final
    assert_stopped(srv, cid, frozen_at, STOP_BOUND_S)
    after = [e for e in srv.motion(RID, cid) if e["ts"] > final["ts"]]
    assert after == [], "the goal went on after it failed"


def test_silent_server_stops_the_goal(robot: ManagedProcess, fake_server: FakeServer) -> None:
    srv = fake_server
    cid = start_goal(srv)
    last_beat = srv.stop_heartbeat()  # a server killed with -9 says nothing more
    final = srv.final_ack(RID, cid, 10)
    assert final["status"] == "failed" and final["reason"].startswith("unsupervised"), final
    took = assert_stopped(srv, cid, last_beat, HEARTBEAT_SILENCE_S + STOP_BOUND_S)
    assert took >= HEARTBEAT_SILENCE_S - 0.05  # it did wait for the full second of silence


def test_estop_aborts_the_goal(robot: ManagedProcess, fake_server: FakeServer) -> None:
    srv = fake_server
    cid = start_goal(srv)
    at = time.time()
    srv.estop(True)
    final = srv.final_ack(RID, cid, 10)
    assert final["status"] == "aborted" and final["reason"] == "e-stop", final
    assert_stopped(srv, cid, at, STOP_BOUND_S)
    refused = srv.send(RID, "goto", {"x": 0.0, "y": 0.0})
    assert srv.final_ack(RID, refused, 10)["reason"] == "e-stop engaged"
    srv.estop(False)


def test_stop_and_another_motion_command_abort_the_goal(robot: ManagedProcess, fake_server: FakeServer) -> None:
    srv = fake_server
    cid = start_goal(srv)
    at = time.time()
    srv.send(RID, "stop")
    final = srv.final_ack(RID, cid, 10)
    assert final["status"] == "aborted" and final["reason"] == "stopped", final
    assert_stopped(srv, cid, at, STOP_BOUND_S)

    cid = start_goal(srv)
    newer = srv.send(RID, "goto", {"x": 0.0, "y": 1.0})
    final = srv.final_ack(RID, cid, 10)
    assert final["status"] == "aborted" and "goto" in final["reason"], final
    srv.ack(RID, newer, "accepted")

    drive = srv.send(RID, "drive", {"linear": 0.0, "angular": 0.5, "duration_s": 0.3})
    final = srv.final_ack(RID, newer, 10)
    assert final["status"] == "aborted" and "drive" in final["reason"], final
    assert srv.final_ack(RID, drive, 10)["status"] == "done"
