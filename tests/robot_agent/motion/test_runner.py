"""The motion runner on its own, with a fake clock and a recording motor driver (the hardware is the only
thing mocked): refusals, the failures the live tests cannot provoke quickly (timeout, stalled, a fence
moved under a running goal), the mapping of what ends a goal to its ack, a looping path, and its
supervision loop on a virtual clock."""

from __future__ import annotations

import asyncio
import math
from typing import Any

import orjson
import pytest

from fleet_protocol import Ack, FollowPathArgs, GotoArgs, Site, SiteMessage, default_pool_site, dumps
from robot_agent.motion import limits
from robot_agent.motion.kinematics import Kinematics
from robot_agent.motion.runner import MotionRunner
from robot_agent.sim.world import Pose, SimWorld
from tests.support.virtual_world import RecordingMotors
from tests.support.virtual_world import VirtualClock as Clock

KIN = Kinematics(wheel_base_m=0.2, max_wheel_speed_mps=0.3, max_linear_mps=0.2, max_angular_rps=1.5)


class Rig:
    def __init__(self, site: Site | None = None, site_known: bool = True, start: Pose | None = None) -> None:
        self.clock = Clock()
        self.world = SimWorld(clock=self.clock, start=start or Pose(0.0, 0.0, 0.0))
        self.motors = RecordingMotors(self.world)
        self.acks: list[Ack] = []
        self.emitted: list[tuple[str, dict[str, Any]]] = []
        self.ended: list[str] = []
        self.runner = MotionRunner(
            kinematics=KIN,
            motors=self.motors,
            send_ack=self.acks.append,
            emit=lambda s, d: self.emitted.append((s, d)),
            end_drive=self.ended.append,
            driving=lambda: False,
            clock=self.clock,
        )
        if site_known:
            self.runner.on_site_payload(dumps(SiteMessage(version=7, site=site)))
        self.beat()
        self.fix()

    def beat(self) -> None:
        self.runner.on_heartbeat_payload(orjson.dumps({"server_id": "s", "ts": 1.0, "seq": 1}))

    def fix(self) -> None:
        p = self.world.pose()
        self.runner.on_fix({"x": p.x, "y": p.y, "z": 0.0, "yaw": p.yaw})

    def run(self, seconds: float, beat: bool = True) -> None:
        for _ in range(round(seconds / 0.05)):
            self.clock.t += 0.025
            self.runner.tick()
            self.clock.t += 0.025
            if beat:
                self.beat()
            self.fix()
            self.runner.tick()

    def final(self, cid: str) -> Ack:
        return [a for a in self.acks if a.id == cid and a.status != "accepted"][-1]


def test_refusals_before_a_goal_starts() -> None:
    rig = Rig(site_known=False)
    rig.runner.start_goto("g1", GotoArgs(x=0.5, y=0.0))
    assert rig.final("g1").reason.startswith("no site received")
    rig = Rig(site=None)  # "no site" published: no fence
    rig.runner.start_goto("g2", GotoArgs(x=5.0, y=0.0))
    assert rig.acks[-1].status == "accepted" and "site v7 (no fence)" in rig.acks[-1].reason
    rig = Rig(site=default_pool_site())
    rig.clock.t += 1.5  # the server went quiet
    rig.fix()
    rig.runner.start_goto("g3", GotoArgs(x=0.5, y=0.0))
    assert rig.final("g3").reason.startswith("unsupervised")


def test_timeout_and_stalled() -> None:
    rig = Rig(site=default_pool_site())
    rig.runner.start_goto("t1", GotoArgs(x=1.5, y=0.0, timeout_s=2.0))
    rig.run(3.0)
    assert rig.final("t1").status == "failed" and rig.final("t1").reason.startswith("timeout")
    assert rig.motors.sets[-1] == (0.0, 0.0)
    rig.runner.start_goto("s1", GotoArgs(x=1.5, y=0.0))
    rig.world.max_speed_mps = 0.0  # the wheels spin, the robot goes nowhere (tangled in weed)
    rig.run(10.0)
    assert rig.final("s1").status == "failed" and rig.final("s1").reason.startswith("stalled")
    assert rig.motors.sets[-1] == (0.0, 0.0)


def test_a_fence_moved_under_a_running_goal_stops_it() -> None:
    rig = Rig(site=default_pool_site())
    rig.runner.start_goto("f1", GotoArgs(x=1.5, y=0.0))
    rig.run(1.0)
    assert rig.runner.goal is not None
    fence = Site(boundary=[[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]], geofence_margin_m=0.1)
    rig.runner.on_site_payload(dumps(SiteMessage(version=8, site=fence)))
    rig.run(3.0)
    final = rig.final("f1")
    assert final.status == "failed" and final.reason.startswith("geofence")
    assert rig.world.pose().x < 0.5  # never reached the new fence
    assert any(s == "geofence" and d["event"] == "stopped" for s, d in rig.emitted)


def test_what_ends_a_goal_decides_its_ack() -> None:
    for reason, status in (
        ("stopped", "aborted"),
        ("e-stop", "aborted"),
        ("link lost", "failed"),
        ("link silent", "failed"),
        ("shutdown", "aborted"),
    ):
        rig = Rig(site=default_pool_site())
        rig.runner.start_goto("e1", GotoArgs(x=1.0, y=0.0))
        rig.run(0.5)
        rig.runner.preempt(reason)
        final = rig.final("e1")
        assert final.status == status, (reason, final)
        assert final.reason.startswith("link_lost") if status == "failed" else final.reason == reason
        assert rig.motors.sets[-1] == (0.0, 0.0) and rig.runner.goal is None
    rig = Rig(site=default_pool_site())
    rig.runner.start_goto("e2", GotoArgs(x=1.0, y=0.0))
    assert rig.runner.check_drive("d1", 0.2, 0.2, 0.5) is None  # a drive takes over
    assert rig.final("e2").status == "aborted" and "drive" in rig.final("e2").reason


def test_a_looping_path_goes_round_until_stopped() -> None:
    rig = Rig(site=default_pool_site())
    square = [[0.5, 0.0], [0.5, 0.5], [0.0, 0.5], [0.0, 0.0]]
    rig.runner.start_path("p1", FollowPathArgs(waypoints=square, loop=True, max_speed=0.2))
    rig.run(30.0)
    ctl = rig.runner.goal.controller if rig.runner.goal else None
    assert ctl is not None and getattr(ctl, "laps", 0) >= 2
    reports = [d for s, d in rig.emitted if s == "motion" and d["command_id"] == "p1"]
    assert max(d["cross_track_m"] for d in reports if d["cross_track_m"] is not None) < 0.1
    rig.runner.preempt("stopped")
    assert rig.final("p1").status == "aborted"
    assert rig.motors.sets[-1] == (0.0, 0.0)


def test_drives_at_the_fence_are_refused_and_away_from_it_taken() -> None:
    fence = Site(boundary=[[-0.5, -1.0], [0.5, -1.0], [0.5, 1.0], [-0.5, 1.0]], geofence_margin_m=0.2)
    rig = Rig(site=fence, start=Pose(0.3, 0.0, 0.0))  # 0.2 m from the fence, facing it
    rig.run(0.3)
    refusal = rig.runner.check_drive("d1", 1.0, 1.0, 0.5)  # full speed at it: 0.3 m/s x 0.35 s reaches 0.405
    assert refusal is not None and refusal.startswith("geofence")
    assert rig.runner.hold is not None  # holds its spot while the operator keeps pushing
    assert any(s == "geofence" and d["event"] == "refused" for s, d in rig.emitted)
    assert rig.runner.check_drive("d2", -1.0, -1.0, 0.5) is None  # backing away is fine
    assert rig.runner.hold is None
    assert rig.runner.check_drive("d3", -1.0, 1.0, 0.5) is None  # so is turning in place
    rig = Rig(site=fence, start=Pose(0.45, 0.0, math.pi))  # drifted out, facing back in
    rig.run(0.3)
    assert rig.runner.check_drive("d4", 0.5, 0.5, 0.5) is None  # heading back in is allowed
    assert rig.runner.check_drive("d5", -0.5, -0.5, 0.5) is not None  # further out is not


def test_a_goal_naming_its_supervisor_needs_that_replicas_heartbeat() -> None:
    """Two server replicas beat; a goal sent by replica "a" (``supervisor``) ends ``unsupervised`` a second
    after "a" falls silent, although "b" still beats; a goal naming none goes on with any beat."""
    rig = Rig(site=default_pool_site())

    def beat(server: str) -> None:
        rig.runner.on_heartbeat_payload(orjson.dumps({"server_id": server, "ts": 1.0, "seq": 1}))

    beat("a")
    rig.runner.start_path("p0", FollowPathArgs(waypoints=[[0.5, 0.0]], supervisor="c"))  # never heard
    assert rig.final("p0").status == "rejected" and "server c" in rig.final("p0").reason
    rig.runner.start_path("p1", FollowPathArgs(waypoints=[[1.5, 0.0], [1.5, 1.0]], supervisor="a"))
    assert rig.acks[-1].status == "accepted"
    for _ in range(10):  # both beat: it drives
        rig.run(0.1, beat=False)
        beat("a")
        beat("b")
    assert rig.runner.goal is not None and rig.motors.sets[-1] != (0.0, 0.0)
    for _ in range(12):  # only "b" beats now
        rig.run(0.1, beat=False)
        beat("b")
    final = rig.final("p1")
    assert final.status == "failed" and final.reason.startswith("unsupervised: no heartbeat from server a"), final
    assert rig.motors.sets[-1] == (0.0, 0.0)
    rig.runner.start_path("p2", FollowPathArgs(waypoints=[[0.0, 0.5]]))  # no supervisor named: "b" will do
    assert rig.acks[-1].status == "accepted"


def test_the_supervision_loop_sleeps_and_reads_time_on_the_injected_clock() -> None:
    """run() on a virtual clock (no real time passes): a goal whose fixes stop fails once 0.3 s of that
    clock passed, ticking every 25 ms while it runs and every 0.2 s once idle; acks carry its wall time."""
    rig = Rig(site=default_pool_site())
    rig.runner.start_goto("v1", GotoArgs(x=1.0, y=0.0))
    assert rig.acks[-1].status == "accepted" and rig.acks[-1].ts == rig.clock.now()

    async def supervise() -> None:
        task = asyncio.create_task(rig.runner.run())
        for _ in range(1000):  # bounded: a runner sleeping on the event loop's clock fails here, not hangs
            if len(rig.clock.slept) >= 20:
                break
            await asyncio.sleep(0)
        task.cancel()
        assert len(rig.clock.slept) >= 20

    asyncio.run(supervise())
    final = rig.final("v1")
    assert final.status == "failed" and final.reason.startswith("no_position: no position fix for"), final
    slept = rig.clock.slept
    active = slept.index(limits.IDLE_TICK_S)  # the sleeps while the goal ran, then the idle ones
    assert set(slept[:active]) == {limits.TICK_S} and set(slept[active:]) == {limits.IDLE_TICK_S}
    failed_after = sum(slept[:active])
    assert failed_after == pytest.approx(limits.FIX_SILENCE_S, abs=limits.TICK_S)  # the first tick past it
    assert final.reason.endswith(f"for {failed_after:.2f} s")
    assert final.ts == pytest.approx(1_700_000_000.0 + 100.0 + failed_after, abs=1e-6)
