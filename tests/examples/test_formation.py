"""examples/formation.py against three simulated robots with every disturbance on: the leader follows a
looping path by itself, the two followers are off-board controllers (client.control). The formation error
is measured from the positions the server stored."""

from __future__ import annotations

import asyncio
import itertools
import math
import statistics
import time

import pytest

from examples.formation import LEFT_SLOT, RIGHT_SLOT, circle_path, run_formation
from tests.support.formation import formation_errors, slot_start, stored_track

RADIUS = 0.7
SECONDS = 24.0
SETTLE_S = 6.0  # the followers start in their slots, but the leader first turns onto its path


@pytest.mark.realtime  # an off-board loop at 20 Hz over REST: its slot error needs it on time (5.3 cm loaded)
def test_two_followers_hold_a_triangle_around_a_path_following_leader(sim_robots, pool_site, fleet):
    lx, ly = RADIUS, 0.0
    (fx1, fy1), (fx2, fy2) = slot_start(LEFT_SLOT, RADIUS), slot_start(RIGHT_SLOT, RADIUS)
    sim_robots(("lead", lx, ly, math.pi / 2), ("left", fx1, fy1, math.pi / 2), ("right", fx2, fy2, math.pi / 2))
    t0 = time.time()
    steps = asyncio.run(run_formation(fleet, "lead", "left", "right", SECONDS, circle_path(RADIUS)))
    t1 = time.time()
    assert steps["left"] > 10 * SECONDS and steps["right"] > 10 * SECONDS, steps  # ~20 Hz set-points
    time.sleep(1.5)  # the last fixes committed

    lead_ts, lead = stored_track(fleet, "lead", t0 + SETTLE_S, t1)
    tracks = {name: stored_track(fleet, name, t0 + SETTLE_S, t1) for name in ("left", "right")}
    # The formation had to move: the leader went a good part of its circle.
    travelled = sum(math.dist((a["x"], a["y"]), (b["x"], b["y"])) for a, b in itertools.pairwise(lead[::10]))
    assert travelled > 0.5, f"the leader hardly moved ({travelled:.2f} m): nothing was tested"

    measured = formation_errors(lead_ts, lead, tracks, {"left": LEFT_SLOT, "right": RIGHT_SLOT})
    for name, errs in measured.slot.items():
        assert len(errs) > 10 * (SECONDS - SETTLE_S), f"{name}: only {len(errs)} stored fixes matched"
        mean, p95, worst = measured.summary(name)
        print(f"{name}: slot error mean {mean * 100:.1f} cm, p95 {p95 * 100:.1f} cm, max {worst * 100:.1f} cm")
        assert mean <= 0.05, f"{name}: mean distance from its slot {mean:.3f} m"
        assert worst <= 0.15, f"{name}: worst distance from its slot {worst:.3f} m"
    sides = measured.sides
    print(f"triangle sides: mean error {statistics.fmean(sides) * 100:.1f} cm, max {max(sides) * 100:.1f} cm")
    assert statistics.fmean(sides) <= 0.05 and max(sides) <= 0.15
