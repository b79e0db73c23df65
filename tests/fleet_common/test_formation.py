"""The formation law (fleet_common/formation.py) on its own: the leader's fit, the slot's motion, and a
follower that reaches and holds a moving, turning slot against a steady current (a unicycle integrated
here: the law is pure, so it needs no simulator process; tests/examples judges it with the real agents)."""

from __future__ import annotations

import math

import pytest

from fleet_common.formation import FormationGains, LeaderState, LeaderTrack, SlotFollower, slot_position, slot_velocity


def test_the_leader_fit_is_exact_on_steady_motion_and_extrapolates():
    track = LeaderTrack(window_s=1.0)
    for k in range(40):  # 20 Hz on a circle of radius 0.5 m at 0.1 rad/s, yaw through +-pi
        t = 100.0 + 0.05 * k
        a = 3.0 + 0.1 * (t - 100.0)
        track.update(0.5 * math.cos(a), 0.5 * math.sin(a), math.atan2(math.cos(a), -math.sin(a)), t)
    state = track.state(102.0)
    assert state is not None
    assert abs(state.omega - 0.1) < 1e-3  # unwrapped across +-pi
    assert math.hypot(state.vx, state.vy) == pytest.approx(0.05, abs=2e-3)
    a = 3.0 + 0.1 * 2.0
    assert math.dist((state.x, state.y), (0.5 * math.cos(a), 0.5 * math.sin(a))) < 2e-3


def test_a_stale_or_empty_track_stops_the_follower():
    law = SlotFollower((-0.3, 0.3))
    assert law.step(0.0, 0.0, 0.0, 10.0, LeaderTrack(), 10.0) == (0.0, 0.0)
    track = LeaderTrack()
    track.update(1.0, 0.0, 0.0, 10.0)
    assert law.step(0.0, 0.0, 0.0, 11.0, track, 11.0) == (0.0, 0.0)  # the leader's fix is 1 s old


def test_the_slot_moves_with_the_leader_and_turns_with_it():
    lead = LeaderState(x=1.0, y=2.0, yaw=math.pi / 2, vx=0.0, vy=0.1, omega=0.2)
    sx, sy = slot_position(lead, (-0.4, 0.3))
    assert math.dist((sx, sy), (1.0 - 0.3, 2.0 - 0.4)) < 1e-9
    fx, fy = slot_velocity(lead, (-0.4, 0.3))
    # r = (-0.3, -0.4) in the world; omega x r = 0.2 * (0.4, -0.3)
    assert math.dist((fx, fy), (0.08, 0.1 - 0.06)) < 1e-9


def _hold_inner_slot(gains: FormationGains) -> float:
    """The worst slot error after 25 s: a leader on a 0.7 m circle at 0.08 m/s, the follower on the inner
    slot, starting off it and facing the wrong way, a 3 cm/s current."""
    offset = (-0.35, 0.3)
    radius, speed, current = 0.7, 0.08, (0.0, -0.03)
    omega = speed / radius
    law = SlotFollower(offset, gains)
    track = LeaderTrack(window_s=law.gains.window_s)

    def leader_at(t: float) -> LeaderState:
        a = omega * t
        x, y = radius * math.cos(a), radius * math.sin(a)
        return LeaderState(x, y, a + math.pi / 2, -speed * math.sin(a), speed * math.cos(a), omega)

    x, y = slot_position(leader_at(0.0), offset)
    x, y, yaw = x + 0.05, y - 0.05, 0.0  # off its slot and facing the wrong way
    cmd = (0.0, 0.0)
    dt, errors = 0.005, []
    for k in range(int(40.0 / dt)):
        t = k * dt
        if k % 10 == 0:  # 20 Hz fixes, the set-point acting at once
            lead = leader_at(t)
            track.update(lead.x, lead.y, lead.yaw, t)
            cmd = law.step(x, y, yaw, t, track, t)
            if t > 25.0:
                errors.append(math.dist((x, y), slot_position(lead, offset)))
        v, w = cmd
        x += (v * math.cos(yaw) + current[0]) * dt
        y += (v * math.sin(yaw) + current[1]) * dt
        yaw += w * dt
    return max(errors)


def test_a_follower_holds_a_turning_slot_against_a_current():
    assert _hold_inner_slot(FormationGains()) < 0.01


def test_without_the_integral_the_current_pushes_the_follower_off_its_slot():
    """The same run with no integral action: the proportional pull alone sits current / k_pos off."""
    assert _hold_inner_slot(FormationGains(k_int=0.0)) > 0.015
