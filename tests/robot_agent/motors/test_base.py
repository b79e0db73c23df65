"""``clamp_unit``, the last step of every motor driver's ``set``: a set-point that is not a finite number (a
broken estimate upstream) stops the wheels; ``min``/``max`` alone pass NaN on to the motors."""

from __future__ import annotations

import math

import pytest

from robot_agent.motors.base import clamp_unit
from robot_agent.motors.sim import SimMotorDriver
from robot_agent.sim.world import Pose, SimWorld


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_set_point_that_is_not_a_finite_number_becomes_zero(value: float) -> None:
    assert clamp_unit(value) == 0.0


def test_finite_set_points_are_kept_within_one() -> None:
    assert [clamp_unit(v) for v in (-3.0, -0.25, 0.0, 0.5, 7)] == [-1.0, -0.25, 0.0, 0.5, 1.0]


def test_a_nan_set_point_never_moves_the_simulated_robot() -> None:
    now = [100.0]
    world = SimWorld(start=Pose(0.5, -0.25, 0.0), max_speed_mps=0.3, motor_tau_s=0.0, clock=lambda: now[0])
    driver = SimMotorDriver(world)
    driver.set(math.nan, math.nan)
    now[0] += 2.0
    assert (driver.left, driver.right) == (0.0, 0.0)
    assert world.wheel_speeds() == (0.0, 0.0)
    pose = world.pose()
    assert (pose.x, pose.y) == (0.5, -0.25)
    driver.set(0.5, 0.5)  # the same driver and world do move on a real set-point: the check above could fail
    now[0] += 1.0
    assert world.pose().x > 0.6
