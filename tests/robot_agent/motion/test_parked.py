"""A parked robot keeps clear (robot_agent/motion/parked.py, GuardedMotors.keep_clear): the runner behind the
collision guard in a simulated world on a virtual clock, with the fleet's poses fed as the servers send them.
A neighbour without the filter comes at a robot that has reached its goal: it backs away, through the filter,
only while it may (a goal ended by itself, the server heard); a stop or a lost link leaves it where it is."""

from __future__ import annotations

import math
from typing import Any

import orjson

from fleet_protocol import Ack, AvoidanceSettings, FleetPoses, GotoArgs, Site, SiteMessage, default_pool_site, dumps
from fleet_protocol.neighbours import PoseRow
from robot_agent.motion.collision_guard import GuardedMotors
from robot_agent.motion.kinematics import Kinematics
from robot_agent.motion.neighbours import NeighbourTable
from robot_agent.motion.runner import MotionRunner
from robot_agent.sim.world import Pose, SimWorld
from tests.support.virtual_world import RecordingMotors, VirtualClock

KIN = Kinematics(wheel_base_m=0.2, max_wheel_speed_mps=0.3, max_linear_mps=0.2, max_angular_rps=1.5)


class Rig:
    """One robot at the origin, facing +x; ``old`` (no filter) is wherever the test puts it."""

    def __init__(self, site: Site | None = None) -> None:
        self.clock = VirtualClock()
        self.world = SimWorld(clock=self.clock, start=Pose(0.0, 0.0, 0.0))
        self.wheels = RecordingMotors(self.world)
        self.acks: list[Ack] = []
        self.emitted: list[tuple[str, dict[str, Any]]] = []
        self.guard = GuardedMotors(
            self.wheels,
            kinematics=KIN,
            neighbours=NeighbourTable("me"),
            emit=lambda s, d: self.emitted.append((s, d)),
            clock=self.clock,
        )
        self.runner = MotionRunner(
            kinematics=KIN,
            motors=self.guard,
            send_ack=self.acks.append,
            emit=lambda s, d: self.emitted.append((s, d)),
            end_drive=lambda reason: None,
            driving=lambda: False,
            clock=self.clock,
        )
        msg = SiteMessage(version=1, site=site or default_pool_site(), avoidance=AvoidanceSettings())
        self.runner.on_site_payload(dumps(msg))
        self.old: tuple[float, float, float] | None = None  # x, y, vx of the old-framework robot
        self.seq = 0
        self.step(beat=True)

    def step(self, beat: bool = True) -> None:
        """50 ms: the old robot moves, the server's poses and heartbeat (``beat``), a fix, a tick."""
        self.clock.t += 0.05
        self.seq += 1
        rows: list[PoseRow] = []
        if self.old is not None:
            x, y, vx = self.old
            self.old = (x + vx * 0.05, y, vx)
            rows.append(("old", self.old[0], y, None, vx, 0.0, 0.05, False))
        if beat:
            poses = FleetPoses(server_id="s", ts=self.clock.now(), seq=self.seq, robots=rows)
            self.guard.on_poses_payload(dumps(poses))
            self.runner.on_heartbeat_payload(orjson.dumps({"server_id": "s", "ts": 1.0, "seq": self.seq}))
        p = self.world.pose()
        self.runner.on_fix({"x": p.x, "y": p.y, "z": 0.0, "yaw": p.yaw})
        self.runner.tick()

    def run(self, seconds: float, beat: bool = True) -> None:
        for _ in range(round(seconds / 0.05)):
            self.step(beat)

    def park(self) -> None:
        """A goto that ends done, a little ahead."""
        self.runner.start_goto("g", GotoArgs(x=0.3, y=0.0))
        self.run(6.0)
        assert [a.status for a in self.acks if a.id == "g"][-1] == "done"

    def gap(self) -> float:
        assert self.old is not None
        p = self.world.pose()
        return math.hypot(self.old[0] - p.x, self.old[1] - p.y)

    def keep_clear_records(self) -> list[dict[str, Any]]:
        return [d for s, d in self.emitted if s == "avoidance" and d["cause"] == "keep_clear"]


def test_a_parked_robot_backs_away_from_an_old_robot_driven_at_it() -> None:
    rig = Rig()
    rig.park()
    here = rig.world.pose().x
    rig.old = (here + 1.0, 0.0, -0.05)  # 1 m ahead, coming at it at 5 cm/s for 24 s: 0.2 m past where it is
    closest = math.inf
    for _ in range(480):
        rig.step()
        closest = min(closest, rig.gap())
    assert closest >= 0.3, closest  # the site's 0.3 m between centres (it never came nearer than it keeps)
    assert rig.world.pose().x < here - 0.5  # it backed away ahead of the old robot, all the way
    records = rig.keep_clear_records()
    assert records and records[0]["event"] == "active" and records[0]["neighbour"] == "old"
    assert rig.runner.active  # moving on its own: the link watchdog watches it


def test_standing_still_where_it_is_safe_moves_nothing() -> None:
    """A neighbour near but still, or going away, moves nothing: robots parked in a row stay parked. One inside
    the safety distance is left to it, and no more."""
    rig = Rig()
    rig.park()
    sets = len(rig.wheels.sets)
    here = rig.world.pose().x
    # outside the distance kept: 0.34 m with its margins from the point 4 cm ahead that the filter steers
    rig.old = (here + 0.4, 0.0, 0.0)
    rig.run(3.0)
    rig.old = (here + 0.4, 0.0, 0.03)  # going away
    rig.run(3.0)
    assert all(s == (0.0, 0.0) for s in rig.wheels.sets[sets:]), rig.wheels.sets[sets:]
    assert rig.keep_clear_records() == [] and not rig.runner.active
    rig.old = (here + 0.28, 0.0, 0.0)  # inside it (the check above could have failed: now it moves)
    rig.run(4.0)
    assert rig.keep_clear_records() != [] and not rig.runner.active  # it moved, and stopped again
    assert 0.36 <= rig.gap() <= 0.4, rig.gap()  # at the distance kept, not farther


def test_a_stop_or_a_lost_link_leaves_a_parked_robot_where_it_is_and_a_silent_server_pauses_it() -> None:
    for reason in ("stopped", "link silent", "e-stop"):
        rig = Rig()
        rig.park()
        rig.old = (rig.world.pose().x + 0.6, 0.0, -0.05)
        rig.run(5.0)
        assert rig.runner.active, reason  # keeping clear
        rig.runner.preempt(reason)
        assert rig.wheels.sets[-1] == (0.0, 0.0) and not rig.runner.active, reason
        sets = len(rig.wheels.sets)
        rig.run(3.0)  # the old robot keeps coming: the operator's stop stands
        assert all(s == (0.0, 0.0) for s in rig.wheels.sets[sets:]), reason
    rig = Rig()
    rig.park()
    rig.old = (rig.world.pose().x + 0.6, 0.0, -0.05)
    rig.run(5.0)
    assert rig.runner.active
    rig.run(0.45, beat=False)  # the server went quiet (no heartbeat, no poses) ...
    assert rig.runner.active and rig.wheels.sets[-1] != (0.0, 0.0)  # ... still keeping clear before 0.5 s
    rig.run(0.1, beat=False)  # its poses are stale at 0.5 s: it stops
    assert rig.wheels.sets[-1] == (0.0, 0.0) and not rig.runner.active
    rig.run(0.5)  # the server is back (a fix dropout alike): it keeps clear again, it was never told to stop
    assert rig.runner.active and rig.wheels.sets[-1] != (0.0, 0.0)


def test_a_goal_aborted_leaves_it_parked_and_one_refused_at_the_fence_never_moves_it_out() -> None:
    rig = Rig()
    rig.runner.start_goto("g", GotoArgs(x=0.3, y=0.0))
    rig.run(0.5)
    rig.runner.start_goto("h", GotoArgs(x=0.0, y=0.0))  # superseded: g aborted, h runs
    rig.run(6.0)
    assert rig.runner.parked.armed  # h ended done
    rig.runner.preempt("superseded by a drive command")
    assert not rig.runner.parked.armed
    # a fence right behind it: it backs away up to where any motion stops (its stopping point within half the
    # fence's margin of it), and stands there: the old robot, without a filter, is beyond what it can do
    fence = Site(boundary=[[-0.25, -1.0], [2.0, -1.0], [2.0, 1.0], [-0.25, 1.0]], geofence_margin_m=0.1)
    rig = Rig(site=fence)
    rig.park()
    rig.old = (rig.world.pose().x + 0.8, 0.0, -0.05)
    lowest = math.inf
    for _ in range(480):
        rig.step()
        lowest = min(lowest, rig.world.pose().x)
    assert -0.25 + 0.05 < lowest < -0.15, lowest  # it went to the fence, never past the motion's limit
    assert rig.wheels.sets[-1] == (0.0, 0.0)
