"""Differential-drive kinematics of the simulated robot, on a controllable clock."""

from __future__ import annotations

import math
import threading

import pytest

from robot_agent.sim.world import PoolBounds, Pose, SimTag, SimWorld, default_tags, start_pose_for


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


def make(clock: FakeClock, **kw: object) -> SimWorld:
    return SimWorld(start=Pose(0.0, 0.0, 0.0), max_speed_mps=0.3, wheel_base_m=0.2, motor_tau_s=0.0, clock=clock, **kw)  # type: ignore[arg-type]


def test_straight_line_distance_is_speed_times_time() -> None:
    clock = FakeClock()
    w = make(clock)
    w.set_wheels(0.5, 0.5)
    clock.advance(2.0)
    p = w.pose()
    assert p.x == pytest.approx(0.3 * 0.5 * 2.0, abs=1e-9)
    assert p.y == pytest.approx(0.0, abs=1e-9)
    assert p.yaw == pytest.approx(0.0, abs=1e-12)


def test_heading_is_respected_and_backward_moves_back() -> None:
    clock = FakeClock()
    w = SimWorld(start=Pose(0.0, 0.0, math.pi / 2), motor_tau_s=0.0, clock=clock)
    w.set_wheels(-1.0, -1.0)
    clock.advance(1.0)
    p = w.pose()
    assert p.x == pytest.approx(0.0, abs=1e-9)
    assert p.y == pytest.approx(-0.3, abs=1e-9)


def test_turn_left_in_place_increases_yaw_at_the_expected_rate() -> None:
    clock = FakeClock()
    w = make(clock)
    w.set_wheels(-0.5, 0.5)  # turn left: right wheel forward
    clock.advance(0.5)
    p = w.pose()
    omega = (0.15 - (-0.15)) / 0.2  # rad/s
    assert p.yaw == pytest.approx(omega * 0.5, abs=1e-9)
    assert math.hypot(p.x, p.y) == pytest.approx(0.0, abs=1e-9)
    accel, gyro = w.imu()
    assert gyro[2] == pytest.approx(omega)
    assert accel[2] == pytest.approx(9.81)


def test_arc_matches_the_closed_form_circle() -> None:
    clock = FakeClock()
    w = make(clock)
    w.set_wheels(0.5, 1.0)
    vl, vr = 0.15, 0.3
    v, omega = (vl + vr) / 2, (vr - vl) / 0.2
    radius = v / omega
    clock.advance(1.3)
    p = w.pose()
    theta = omega * 1.3
    assert p.x == pytest.approx(radius * math.sin(theta), abs=1e-9)
    assert p.y == pytest.approx(radius * (1 - math.cos(theta)), abs=1e-9)
    assert p.yaw == pytest.approx(theta, abs=1e-9)


def test_integration_is_substepped_at_least_100_hz() -> None:
    clock = FakeClock()
    w = make(clock)
    assert w.max_step_s <= 0.01
    w.set_wheels(1.0, 1.0)
    clock.advance(10.0)  # drives into the east wall: clamped by the sub-steps, not overshooting
    p = w.pose()
    assert p.x == pytest.approx(2.0 - w.robot_radius_m)
    assert w.wall_hits > 0


def test_walls_clamp_every_side() -> None:
    clock = FakeClock()
    b = PoolBounds(-1.0, 1.0, -0.5, 0.5)
    w = SimWorld(start=Pose(0.0, 0.0, -math.pi / 2), motor_tau_s=0.0, bounds=b, clock=clock)
    w.set_wheels(1.0, 1.0)
    clock.advance(5.0)
    assert w.pose().y == pytest.approx(-0.5 + w.robot_radius_m)


def test_motor_lag_gives_finite_acceleration() -> None:
    clock = FakeClock()
    w = SimWorld(start=Pose(0.0, 0.0, 0.0), motor_tau_s=0.1, clock=clock)
    w.set_wheels(1.0, 1.0)
    clock.advance(0.05)
    accel, _ = w.imu()
    assert 0.5 < accel[0] < 3.0  # 0.3 m/s in ~0.1 s
    clock.advance(1.0)
    vl, vr = w.wheel_speeds()
    assert vl == pytest.approx(0.3, rel=1e-3) and vr == pytest.approx(0.3, rel=1e-3)


def test_wheel_setpoints_are_clamped() -> None:
    clock = FakeClock()
    w = make(clock)
    w.set_wheels(5.0, -5.0)
    clock.advance(0.01)
    assert w.wheel_speeds() == (pytest.approx(0.3), pytest.approx(-0.3))


def test_start_pose_is_deterministic_and_inside_the_pool() -> None:
    a, b = start_pose_for("robot-1"), start_pose_for("robot-1")
    assert a == b
    poses = {start_pose_for(f"r{i}") for i in range(50)}
    assert len(poses) == 50
    for p in poses:
        assert -1.5 <= p.x <= 1.5 and -1.5 <= p.y <= 1.5 and -math.pi <= p.yaw <= math.pi


def test_default_tags_hang_on_the_walls_facing_inwards() -> None:
    tags = default_tags()
    assert len({t.id for t in tags}) == len(tags) >= 4
    for t in tags:
        assert isinstance(t, SimTag)
        assert max(abs(t.x), abs(t.y)) == pytest.approx(2.0)
        # the face looks towards the pool centre
        to_centre = math.atan2(-t.y, -t.x)
        assert math.cos(t.yaw - to_centre) == pytest.approx(1.0)
        assert t.position == (t.x, t.y, t.z)


def test_concurrent_readers_and_writers_are_consistent() -> None:
    w = SimWorld(start=Pose(0.0, 0.0, 0.0))
    errors: list[BaseException] = []

    def hammer(i: int) -> None:
        try:
            for k in range(300):
                if i % 2:
                    w.set_wheels(((k % 3) - 1) * 0.5, 0.5)
                else:
                    p = w.pose()
                    assert math.isfinite(p.x) and math.isfinite(p.y) and -math.pi <= p.yaw <= math.pi
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=hammer, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
