"""Separation figures (backend/services/runs/separation.py) on hand-made tracks whose distances are known:
the other robot interpolated to each sample's time (samples interleaved, never at the same instants), no
guessing across a silent robot, episodes counted and timed where the distance crosses the limit, the
avoidance stream's interventions, and the work bounded however many robots."""

from __future__ import annotations

import math

import numpy as np
import pytest

from backend.services.runs.separation import (
    CONTACT_M,
    PAIR_WORK_BUDGET,
    Track,
    episodes_below,
    interpolate,
    interventions,
    sample_cap,
    separation,
)


def _crossing(offset_y: float, t0: float = 100.0) -> dict[str, Track]:
    """a drives +x, b drives -x on a line ``offset_y`` away, both at 1 m/s; their x meet at t0 + 1. a's
    samples are at t0 + 0.0, 0.1, ... and b's at t0 + 0.05, 0.15, ...: b is never sampled at the meeting."""
    ta = t0 + np.arange(0, 21) * 0.1
    tb = t0 + 0.05 + np.arange(0, 20) * 0.1
    a = Track(ta, -1.0 + (ta - t0), np.zeros(ta.size))
    b = Track(tb, 1.0 - (tb - t0), np.full(tb.size, offset_y))
    return {"a": a, "b": b}


def _episode_s(offset_y: float, limit: float) -> float:
    """How long the crossing stays under ``limit``: |2(t - t0 - 1)| < sqrt(limit² - offset²)."""
    return math.sqrt(limit**2 - offset_y**2)


def test_the_closest_approach_interpolates_the_other_robot_to_each_sample() -> None:
    stats = separation(_crossing(0.15), {}, 0.3, 100.0)
    assert stats.closest is not None
    # at t0 + 1 a is sampled at x = 0 and b, interpolated there, is at x = 0 too: 0.15 m. Without the
    # interpolation the nearest samples of b (0.05 s away, 0.05 m along) would give 0.18 m.
    assert stats.closest.distance_m == pytest.approx(0.15, abs=1e-9)
    assert stats.closest.ts == pytest.approx(101.0)
    assert stats.closest.robots == ("a", "b")
    [pair] = stats.pairs
    assert pair.samples == 19 + 20  # a's first and last samples have no sample of b on one side: not measured
    assert pair.violations == 1 and stats.violations == 1
    assert pair.violation_s == pytest.approx(_episode_s(0.15, 0.3), abs=0.01)
    assert pair.contacts == 1 and stats.contacts == 1
    assert pair.contact_s == pytest.approx(_episode_s(0.15, CONTACT_M), abs=0.01)
    assert stats.contact_m == pytest.approx(0.2) and stats.min_separation_m == 0.3
    assert stats.samples == {"a": 21, "b": 20} and stats.step == {"a": 1, "b": 1}


def test_nothing_happened_counts_nothing_once_the_counter_is_shown_to_count() -> None:
    tracks = _crossing(0.5)
    # the counter can count on these very tracks: with a limit above their closest approach, one episode
    could = separation(tracks, {}, 0.6, 100.0)
    assert could.violations == 1 and could.violation_s == pytest.approx(_episode_s(0.5, 0.6), abs=0.01)
    stats = separation(tracks, {}, 0.3, 100.0)
    assert stats.closest is not None and stats.closest.distance_m == pytest.approx(0.5, abs=1e-9)
    assert stats.pairs[0].samples > 0  # measured, not skipped
    assert (stats.violations, stats.violation_s, stats.contacts, stats.contact_s) == (0, 0.0, 0, 0.0)
    assert (stats.interventions, stats.intervention_s, stats.intervention_min_distance_m) == (0, 0.0, None)


def test_a_silent_robot_is_not_guessed_at() -> None:
    t = np.array([0.0, 0.5, 3.0, 3.5])  # silent for 2.5 s
    track = Track(t, np.array([0.0, 0.5, 3.0, 3.5]), np.zeros(4))
    x, _, ok = interpolate(track, np.array([-0.1, 0.0, 0.25, 1.0, 2.9, 3.5, 3.6]))
    assert ok.tolist() == [False, True, True, False, False, True, False]
    assert x[ok].tolist() == pytest.approx([0.0, 0.25, 3.5])
    # the other robot passes right through a's place while a says nothing: not measured, not a contact
    a = Track(t, np.zeros(4), np.zeros(4))
    tb = np.arange(0.0, 3.51, 0.1)
    b = Track(tb, np.where((tb > 1.0) & (tb < 2.5), 0.0, 2.0), np.zeros(tb.size))
    stats = separation({"a": a, "b": b}, {}, 0.3, 0.0)
    assert stats.contacts == 0 and stats.closest is not None and stats.closest.distance_m == pytest.approx(2.0)


def test_episodes_split_at_a_crossing_back_and_at_a_hole_in_the_data() -> None:
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 10.0, 11.0])
    d = np.array([1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
    count, total = episodes_below(t, d, 0.5)
    # [0.5, 1.5], [2.5, 4.0] (the hole ends it at its last sample), [10.0, 10.5]
    assert count == 3
    assert total == pytest.approx(1.0 + 1.5 + 0.5)
    assert episodes_below(t, d + 0.6, 0.5) == (0, 0.0)
    assert episodes_below(np.array([]), np.array([]), 0.5) == (0, 0.0)


def test_interventions_are_episodes_of_the_avoidance_stream() -> None:
    def active(dur: float, dist: float) -> dict[str, object]:
        return {"event": "active", "cause": "barrier", "neighbour": "b", "distance_m": dist, "duration_s": dur}

    messages = [
        (10.0, active(0.0, 0.40)),
        (10.1, active(0.1, 0.35)),
        (10.5, {"event": "cleared", "duration_s": 0.5}),
        (20.0, active(0.0, 0.33)),
        (20.2, active(0.2, 0.31)),
        # its "cleared" was lost: the next one's duration starts again
        (30.0, active(0.0, 0.50)),
        (30.3, active(0.3, 0.45)),
        (31.0, {"event": "cleared", "duration_s": 1.0}),
        (40.0, {"event": "cleared", "duration_s": 0.0}),  # no episode open: nothing
    ]
    robot = interventions(messages, 0.0)
    assert robot.count == 3
    assert robot.duration_s == pytest.approx(0.5 + 0.2 + 1.0)
    assert robot.min_distance_m == pytest.approx(0.31)
    # one that began before the stretch counts from the stretch's start
    late = interventions([(5.0, active(3.0, 0.3)), (5.5, {"event": "cleared"})], 4.0)
    assert (late.count, late.duration_s) == (1, pytest.approx(1.5))
    stats = separation({}, {"a": messages, "b": []}, 0.3, 0.0)
    assert stats.interventions == 3 and stats.intervention_min_distance_m == pytest.approx(0.31)
    assert stats.interventions_by_robot["b"].count == 0 and stats.closest is None and stats.pairs == []


@pytest.mark.parametrize("robots", [2, 6, 20, 100])
def test_the_work_is_bounded_however_many_robots(robots: int) -> None:
    cap = sample_cap(robots)
    assert cap >= 100
    assert robots * (robots - 1) * cap <= max(PAIR_WORK_BUDGET, robots * (robots - 1) * 100)
