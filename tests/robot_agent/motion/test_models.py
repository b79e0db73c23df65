"""The pure parts: argument and site models, kinematics, the geofence geometry, the simulator's disturbances,
and the controllers in a fast simulated loop (a fake clock, every disturbance on)."""

from __future__ import annotations

import itertools
import math
import random
import statistics

import pytest
from pydantic import ValidationError

from fleet_protocol import ProtocolError, Site, SiteMessage, decode_site, default_pool_site
from robot_agent.motion.controller import DriftObserver, GotoController
from robot_agent.motion.geofence import Geofence
from robot_agent.motion.kinematics import Kinematics
from robot_agent.sim.disturbances import Disturbance, SimDisturbances
from robot_agent.sim.world import Pose, SimWorld

KIN = Kinematics(wheel_base_m=0.2, max_wheel_speed_mps=0.3, max_linear_mps=0.2, max_angular_rps=1.5)
SQUARE = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]


@pytest.mark.parametrize(
    "site",
    [
        {"boundary": [[0, 0], [1, 1], [1, 0], [0, 1]]},  # a bow-tie: self-intersecting
        {"boundary": []},
        {"boundary": [[0, 0], [1, 1], [2, 2]]},  # no area
        {"boundary": SQUARE, "keepouts": [[[0, 0], [0.1, 0.1], [0.1, 0], [0, 0.1]]]},
        {
            "boundary": SQUARE,
            "tags": [{"id": 1, "size_m": 0.1, "pose": {"x": 0}}, {"id": 1, "size_m": 0.1, "pose": {"x": 1}}],
        },
        {"boundary": [[0, 0], [1e9, 0], [0, 1]]},
        {"boundary": SQUARE, "geofence_margin_m": True},
    ],
)
def test_bad_sites_are_refused(site: dict) -> None:
    with pytest.raises(ValidationError):
        Site.model_validate(site)


def test_site_message_no_site_and_empty_payload() -> None:
    assert decode_site(b'{"version": 3, "site": null}').site is None
    with pytest.raises(ProtocolError):
        decode_site(b"")
    with pytest.raises(ProtocolError):
        decode_site(b'{"site": null}')  # no version: cannot say what a goal was checked against
    assert SiteMessage(version=1, site=default_pool_site()).site is not None


def test_kinematics_limits_and_turn_priority() -> None:
    w = KIN.mix(0.1, 0.0)
    assert (w.left, w.right, w.clamped) == (pytest.approx(1 / 3), pytest.approx(1 / 3), False)
    w = KIN.mix(1.0, 0.0)
    assert w.linear == 0.2 and w.clamped
    w = KIN.mix(0.2, 1.5)  # a wheel would need 0.35 m/s: the forward speed gives way, the turn is kept
    assert w.angular == 1.5 and w.linear == pytest.approx(0.15) and w.right == pytest.approx(1.0) and w.clamped
    assert KIN.body(w.left, w.right) == (pytest.approx(w.linear), pytest.approx(w.angular))
    assert KIN.mix(-5.0, -50.0).linear == pytest.approx(-0.15)


def test_geofence_regions() -> None:
    fence = Geofence(
        Site(
            boundary=[[-1, -1], [1, -1], [1, 1], [-1, 1]],
            keepouts=[[[0.3, -0.1], [0.5, -0.1], [0.5, 0.1], [0.3, 0.1]]],
            geofence_margin_m=0.1,
        )
    )
    assert fence.point_problem(0.0, 0.0) is None
    assert "outside the boundary" in (fence.point_problem(1.2, 0) or "")
    assert "margin" in (fence.point_problem(0.95, 0) or "")
    assert "keep-out 0" in (fence.point_problem(0.4, 0) or "")
    assert "crosses keep-out 0" in (fence.leg_problem((0.0, 0.0), (0.8, 0.0)) or "")
    assert "leaves the safe region" in (fence.path_problem([(0.0, 0.0), (0.8, 0.0)]) or "")
    # motion: heading out near the edge stops, heading in (even from outside) goes on
    assert fence.motion_problem(0.9, -0.5, 0.2, 0.0, 0.35) is not None  # 0.97: within 5 cm of the fence
    assert fence.motion_problem(0.85, -0.5, 0.2, 0.0, 0.35) is None  # 0.92: not yet
    assert fence.motion_problem(0.9, -0.5, -0.2, 0.0, 0.35) is None
    assert fence.motion_problem(0.98, -0.5, -0.1, 0.0, 0.35) is None
    assert fence.motion_problem(0.98, -0.5, 0.05, 0.0, 0.35) is not None
    assert fence.motion_problem(0.1, 0.0, 0.2, 0.0, 0.35) is None  # 7 cm ahead is still clear
    assert fence.motion_problem(0.2, 0.0, 0.2, 0.0, 0.35) is not None  # the keep-out's half margin is near


def test_disturbances_are_off_by_default_and_as_named_when_on() -> None:
    off = Disturbance(SimDisturbances())
    assert off.current(100.0) == (0.0, 0.0) and off.latency() == 0.0 and off.fix_noise() == (0.0, 0.0, 0.0)
    on = Disturbance(SimDisturbances(disturbances=True, seed=1))
    speeds, headings = [], []
    for k in range(3600):
        cx, cy = on.current(float(k))
        speeds.append(math.hypot(cx, cy))
        headings.append(math.atan2(cy, cx))
    assert min(speeds) >= 0.01 - 1e-9 and max(speeds) <= 0.03 + 1e-9
    turn = max(abs(math.remainder(b - a, 2 * math.pi)) for a, b in itertools.pairwise(headings))
    assert 0 < turn < 0.1  # radians per second: it changes, slowly
    noise = [on.fix_noise()[0] for _ in range(5000)]
    assert 0.0045 < statistics.pstdev(noise) < 0.0055
    assert all(0.02 <= on.latency() <= 0.05 for _ in range(100))
    assert on.wheel_gain[0] != on.wheel_gain[1]
    t, gaps, last = 0.0, [], 0.0
    while t < 600:
        if on.fix_available(t):
            if t - last > 0.051:
                gaps.append(t - last)
            last = t
        t += 0.05
    assert 20 < len(gaps) < 150 and max(gaps) < 0.3  # a dropout every ~10 s, each shorter than 0.3 s
    assert not Disturbance(SimDisturbances(disturbances=True, current=False)).current_on


class FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_latency_delays_the_wheels() -> None:
    clock = FakeClock()
    world = SimWorld(
        clock=clock,
        disturbance=Disturbance(
            SimDisturbances(
                disturbances=True, latency_min_s=0.03, latency_max_s=0.03, actuator_noise=0.0, current=False, seed=2
            )
        ),
    )
    world.set_wheels(1.0, 1.0)
    clock.t += 0.029
    assert world.wheel_speeds() == (0.0, 0.0)
    clock.t += 0.1
    assert min(world.wheel_speeds()) > 0.2


def run_goals(count: int, seed: int, with_yaw: bool, limit_s: float) -> list[float]:
    """Random goals with 20 Hz control on noisy, dropping fixes; the true error of each one reached."""
    rng = random.Random(seed)
    errors = []
    for n in range(count):
        clock = FakeClock()
        world = SimWorld(
            start=Pose(rng.uniform(-1.7, 1.7), rng.uniform(-1.7, 1.7), rng.uniform(-3, 3)),
            clock=clock,
            disturbance=Disturbance(SimDisturbances(disturbances=True, seed=n)),
        )
        gx, gy = rng.uniform(-1.7, 1.7), rng.uniform(-1.7, 1.7)
        ctl, obs = GotoController(gx, gy, None, 0.05, 0.15, KIN), DriftObserver()
        for _ in range(int(limit_s * 20)):
            clock.t += 0.05
            fix = world.lighthouse_fix()
            if fix is None:
                continue
            step = ctl.step(obs.update(fix.x, fix.y, fix.yaw if with_yaw else None, clock.t))
            if step.done:
                world.set_wheels(0.0, 0.0)
                p = world.pose()
                errors.append(math.hypot(p.x - gx, p.y - gy))
                break
            w = KIN.mix(step.linear, step.angular)
            obs.commanded(w.linear, w.angular)
            world.set_wheels(w.left, w.right)
    return errors


def test_goto_controller_in_a_fast_disturbed_simulation() -> None:
    """Twenty random goals: every one reached within 5 cm (true position) in 60 s."""
    errors = run_goals(20, seed=5, with_yaw=True, limit_s=60)
    assert len(errors) == 20 and max(errors) <= 0.05


def test_goto_without_a_heading_from_the_lighthouse() -> None:
    """A Lighthouse module that sends no yaw: the heading comes from the track; 19 of 20 measured here."""
    errors = run_goals(20, seed=3, with_yaw=False, limit_s=90)
    assert len(errors) >= 18 and max(errors) <= 0.05, errors


def test_disturbance_switches_from_the_command_line() -> None:
    from robot_agent.cli import build_parser
    from robot_agent.config import load_settings

    def settings(*argv: str) -> SimDisturbances:
        cli = {k: v for k, v in vars(build_parser().parse_args(["--robot-id", "r1", *argv])).items() if v is not None}
        return load_settings(cli, environ={}).sim

    assert not settings().disturbances  # plain --simulate: the perfect world
    on = settings("--disturbances")
    assert on.disturbances and on.current
    no_current = settings("--disturbances", "--no-current")
    assert no_current.disturbances and not no_current.current
    assert not Disturbance(no_current).current_on and Disturbance(no_current).fix_noise_on


@pytest.mark.parametrize("linear, angular", [(math.nan, 0.0), (0.1, math.nan), (math.inf, 0.0), (0.0, -math.inf)])
def test_kinematics_turns_a_velocity_that_is_not_a_finite_number_into_a_stop(linear: float, angular: float) -> None:
    w = KIN.mix(linear, angular)
    assert (w.left, w.right, w.linear, w.angular, w.clamped) == (0.0, 0.0, 0.0, 0.0, True)
