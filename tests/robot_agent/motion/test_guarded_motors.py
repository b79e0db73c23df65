"""The collision guard on its own (robot_agent/motion/collision_guard.py, neighbours.py, give_way.py): what it
gives the motors for what it is asked, with neighbours fed as the servers' poses messages and a clock the test
moves. The robots in the simulator, behind a real server, are measured in test_collision_guard.py."""

from __future__ import annotations

import math
from typing import Any

import pytest

from fleet_protocol import AvoidanceSettings, FleetPoses, dumps
from robot_agent.motion.collision_guard import GuardedMotors
from robot_agent.motion.controller import Estimate
from robot_agent.motion.give_way import GIVE_WAY_S, STILL_S, GiveWay
from robot_agent.motion.kinematics import Kinematics
from robot_agent.motion.neighbours import NeighbourTable, NeighbourView
from robot_agent.motors.base import MotorDriver

KIN = Kinematics(wheel_base_m=0.2, max_wheel_speed_mps=0.3, max_linear_mps=0.2, max_angular_rps=1.5)
FULL = 0.2 / 0.3  # the wheels' set-point of full forward speed


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def monotonic(self) -> float:
        return self.t

    def now(self) -> float:
        return 1.7e9 + self.t

    async def sleep(self, seconds: float) -> None:
        self.t += seconds


class Wheels(MotorDriver):
    """Hardware stand-in: records what reaches the motors."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, float, float]] = []

    @classmethod
    def create(cls, config: Any, world: Any) -> Wheels:
        return cls()

    def set(self, left: float, right: float) -> None:
        self.calls.append(("set", left, right))

    def stop(self) -> None:
        self.calls.append(("stop", 0.0, 0.0))

    def operable(self) -> tuple[bool, str]:
        return True, ""

    @property
    def last(self) -> tuple[str, float, float]:
        return self.calls[-1]


ON = AvoidanceSettings()


def _guard(avoidance: AvoidanceSettings | None = ON) -> tuple[GuardedMotors, Wheels, Clock, list[Any]]:
    wheels, clock, records = Wheels(), Clock(), []
    guard = GuardedMotors(
        wheels,
        kinematics=KIN,
        neighbours=NeighbourTable("me"),
        emit=lambda stream, data: records.append((stream, data)),
        clock=clock,
    )
    guard.configure(avoidance, 0.3)
    guard.on_pose(Estimate(0.0, 0.0, 0.0))
    return guard, wheels, clock, records


def _poses(guard: GuardedMotors, *rows: tuple[Any, ...]) -> None:
    msg = FleetPoses(server_id="s1", ts=1.7e9, seq=1, robots=[tuple(r) for r in rows])
    guard.on_poses_payload(dumps(msg))


def test_a_site_without_avoidance_leaves_commands_alone() -> None:
    guard, wheels, _, records = _guard(None)
    guard.set(FULL, FULL)  # no poses heard, a neighbour would not matter either
    assert wheels.last == ("set", FULL, FULL) and records == []
    assert guard.goal_problem() is None


def test_without_poses_the_robot_creeps_and_refuses_new_goals() -> None:
    guard, wheels, clock, records = _guard()
    assert guard.goal_problem() is not None and guard.goal_problem().startswith("no_poses")  # type: ignore[union-attr]
    guard.set(FULL, FULL)
    _, left, right = wheels.last
    assert left == right == pytest.approx(0.03 / 0.3)  # the site's creep, 0.03 m/s
    assert records[-1][1]["event"] == "active" and records[-1][1]["cause"] == "no_poses"
    _poses(guard)  # the fleet's poses (nobody else): full speed again at the next fix, and goals may start
    guard.on_pose(Estimate(0.0, 0.0, 0.0))
    guard.refresh()
    assert wheels.last == ("set", FULL, FULL) and guard.goal_problem() is None
    assert records[-1][1]["event"] == "cleared"
    clock.t += 0.6  # silent again for over 0.5 s
    assert guard.goal_problem() is not None


def test_a_neighbour_ahead_slows_the_robot_and_one_behind_or_beside_does_not() -> None:
    guard, wheels, _, records = _guard()
    _poses(guard, ("far", 1.5, 0.0, None, 0.0, 0.0, 0.05, True), ("behind", -0.385, 0.0, None, 0.0, 0.0, 0.05, True))
    guard.set(FULL, FULL)
    assert wheels.last == ("set", FULL, FULL) and records == []  # nobody in the way: as asked
    _poses(guard, ("ahead", 0.42, 0.0, None, 0.0, 0.0, 0.05, True))
    guard.refresh()
    _, left, right = wheels.last
    assert (left + right) / 2 < 0.5 * FULL  # held back
    assert records[-1][1]["cause"] == "barrier" and records[-1][1]["neighbour"] == "ahead"
    guard.set(-FULL, -FULL)  # backing away from it: still held, the robot "behind" is in that way now
    assert wheels.last != ("set", -FULL, -FULL)
    guard, wheels, _, records = _guard()
    _poses(guard, ("ahead", 0.46, 0.0, None, 0.0, 0.0, 0.05, True))
    guard.set(-FULL, -FULL)  # backing away from the one ahead, nobody behind: obeyed as asked
    assert wheels.last == ("set", -FULL, -FULL) and records == []


def test_a_zero_command_stays_zero_and_stop_goes_straight_to_the_motors() -> None:
    guard, wheels, _, _ = _guard()
    _poses(guard, ("close", 0.2, 0.0, None, -0.2, 0.0, 0.0, False))  # an old robot coming at it
    guard.set(0.0, 0.0)
    assert wheels.last == ("set", 0.0, 0.0)  # never moved out of the way: the filter adds no motion
    guard.set(FULL, FULL)
    guard.stop()
    assert wheels.last == ("stop", 0.0, 0.0) and guard.nominal == (0.0, 0.0)
    calls = len(wheels.calls)
    guard.on_pose(Estimate(0.0, 0.0, 0.0))
    guard.refresh()  # a fix after the stop never brings the last command back
    assert len(wheels.calls) == calls


def test_a_stale_neighbour_near_makes_the_robot_creep() -> None:
    guard, wheels, _, records = _guard()
    _poses(guard, ("stale", 0.0, 0.45, None, 0.0, 0.0, 0.8, True))  # beside it, last heard 0.8 s ago
    guard.set(FULL, FULL)
    assert wheels.last[1] == pytest.approx(0.03 / 0.3) and records[-1][1]["cause"] == "stale"
    _poses(guard, ("stale", 0.0, 0.45, None, 0.0, 0.0, 0.05, True))  # heard again: it is not in the way
    guard.refresh()
    assert wheels.last == ("set", FULL, FULL)


def test_the_newest_fix_of_each_robot_is_kept_across_replicas() -> None:
    table = NeighbourTable("me")
    one = FleetPoses(server_id="a", ts=0.0, seq=1, robots=[("r1", 1.0, 0.0, None, 0.0, 0.0, 0.1, True)])
    other = FleetPoses(server_id="b", ts=0.0, seq=1, robots=[("r1", 2.0, 0.0, None, 0.0, 0.0, 0.5, True)])
    assert table.on_payload(dumps(one), 10.0) and table.on_payload(dumps(other), 10.05)
    (view,) = table.views(10.05, 0.0, 0.0, 5.0)
    assert view.x == pytest.approx(1.0) and not view.stale  # replica b's fix is older: a's stands
    assert not table.on_payload(b'{"robots": 1}', 10.1) and table.rejects.total == 1  # counted, not kept
    assert table.views(10.05, 0.0, 0.0, 0.5) == []  # out of range


def test_a_still_robot_held_by_a_first_ranked_neighbour_gives_way_and_the_first_does_not() -> None:
    second, first = GiveWay("r2"), GiveWay("r1")
    for k in range(int(STILL_S * 10) + 2):
        for g in (second, first):
            g.on_pose(k * 0.1, 0.0, 0.0)
    now = STILL_S + 0.2
    r1 = NeighbourView("r1", 0.4, 0.0, 0.05, 0.0, 0.1, True)
    r2 = NeighbourView("r2", 0.4, 0.0, 0.05, 0.0, 0.1, True)
    second.held(now, r1)
    assert second.velocity(now, 0.0, 0.0) is None  # still, but only just held: it had been waiting, idle
    for k in range(int(STILL_S * 10) + 1):  # held at every tick since
        first.held(now + k * 0.1, r2)
        second.held(now + k * 0.1, r1)
    now += STILL_S + 0.05
    first.held(now, r2)
    assert first.velocity(now, 0.0, 0.0) is None  # r1 waits for r2 to give way
    second.held(now, r1)
    vx, vy = second.velocity(now, 0.0, 0.0)  # type: ignore[misc]
    assert vx < 0 and vy < 0 and math.hypot(vx, vy) == pytest.approx(0.1)  # back, and to its right
    assert second.velocity(now + GIVE_WAY_S, 0.0, 0.0) is None
    parked = NeighbourView("r0", 0.4, 0.0, 0.0, 0.0, 0.1, True)
    for k in range(int(STILL_S * 10) + 2):
        first.on_pose(10 + k * 0.1, 0.0, 0.0)
    for k in range(int(STILL_S * 10) + 3):
        first.held(10 + k * 0.1, parked)  # a parked robot never moves aside, whatever its rank
    assert first.velocity(10 + STILL_S + 0.2, 0.0, 0.0) is not None


def test_a_poses_message_late_on_the_way_makes_its_fixes_that_much_older() -> None:
    table = NeighbourTable("me")
    msg = FleetPoses(server_id="a", ts=1000.0, seq=1, robots=[("r1", 1.0, 0.0, None, 0.0, 0.0, 0.1, True)])
    assert table.on_payload(dumps(msg), 50.0, server_now=1000.2)  # 0.2 s in a loaded broker's queue
    (view,) = table.views(50.0, 0.0, 0.0, 5.0)
    assert view.age_s == pytest.approx(0.3) and not view.stale  # 0.1 s old when sent, 0.3 s now
    assert table.heard_recently(50.1)  # it came: the fleet is known
    table.on_payload(dumps(msg), 51.0, server_now=1003.0)  # a clock read far late counts 0.25 s at most
    assert table.views(51.0, 0.0, 0.0, 5.0)[0].age_s == pytest.approx(0.35)
    fresh = NeighbourTable("me")
    fresh.on_payload(dumps(msg), 50.0)  # no clock sync yet: its age as sent
    assert fresh.views(50.0, 0.0, 0.0, 5.0)[0].age_s == pytest.approx(0.1)


def test_a_robot_no_server_lists_any_more_is_no_neighbour_and_no_reason_to_creep() -> None:
    guard, wheels, clock, records = _guard()
    _poses(guard, ("gone", 0.0, 0.45, None, 0.0, 0.0, 0.05, True))
    clock.t += 0.7  # it went offline: the next poses no longer list it, and its fix grows old
    _poses(guard)
    guard.on_pose(Estimate(0.0, 0.0, 0.0))
    assert guard.neighbours.views(clock.t, 0.0, 0.0, 5.0) != []  # listed 0.7 s ago: still stale, still there
    guard.set(FULL, FULL)
    assert wheels.last[1] == pytest.approx(0.03 / 0.3) and records[-1][1]["cause"] == "stale"  # it could be near
    clock.t += 0.4
    _poses(guard)
    guard.on_pose(Estimate(0.0, 0.0, 0.0))
    guard.refresh()
    assert guard.neighbours.views(clock.t, 0.0, 0.0, 5.0) == [] and wheels.last == ("set", FULL, FULL)
