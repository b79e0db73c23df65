"""Re-planning a dropped robot's remaining area, and the swept area a step measures
(backend/services/missions/state.py), pure geometry."""

from __future__ import annotations

import pytest
from shapely.geometry import LineString, box

from backend.services.missions.coverage import plan_coverage, swept, workable_region
from backend.services.missions.state import Coverage, MissionRobot, replan, rings, robots_from_plan
from tests.support.missions import lawn_track

SITE = box(-2, -2, 2, 2)
WIDTH = 0.2


def test_a_second_dropout_hands_over_the_area_the_robot_had_inherited() -> None:
    """b drops: its part goes to a and c. Then a drops before sweeping anything: c gets a's own part AND what a
    had inherited from b (not only a's original part), so together they still cover the whole region."""
    region = workable_region(SITE, SITE, [], 0.25)
    plan = plan_coverage(region, 3, WIDTH, 0.0, 0.3)
    a, b, c = robots_from_plan(["a", "b", "c"], plan)
    coverage = Coverage(rings(region), [], WIDTH)
    coverage.update([a, b, c])
    a_own = len(a.path)
    c_own = len(c.path)
    assert replan(b, [a, c], coverage, 0.0, 0.3) == 2
    inherited = swept([tuple(p) for p in a.path[a_own:]], WIDTH)
    assert inherited.area > 1.0
    c_before = len(c.path)
    assert replan(a, [c], coverage, 0.0, 0.3) == 1
    handed = swept([tuple(p) for p in c.path[c_before:]], WIDTH).intersection(region)
    a_work = swept([tuple(p) for p in a.path[:a_own]], WIDTH).union(inherited).intersection(region)
    assert handed.intersection(a_work).area >= 0.95 * a_work.area, (handed.area, a_work.area)
    # c's planned paths (its own, its share of b's, all of a's) sweep the whole region
    everything = swept([tuple(p) for p in c.path], WIDTH)
    assert len(c.path) > c_own and everything.intersection(region).area >= 0.95 * region.area


def test_a_step_marks_only_the_track_points_added_since_the_last_however_long_the_tracks() -> None:
    """Issue 28: every step of a running mission rebuilt the swept area from the robots' whole tracks (a union
    of buffers, on the event loop), so a step's work grew with the mission. Two robots with 10,000 points
    each (200 m of lanes, an hour's sweep together): once they are marked, a point more per robot is two
    points of work, and the points before are not even read (they are made unreadable here: the union of the
    whole tracks raised on them). The figures agree with the exact union of the tracks."""
    hole = [[1.0, 1.0], [2.0, 1.0], [2.0, 2.5], [1.0, 2.5]]  # a keep-out
    region = box(-5, -5, 5, 5).difference(box(1.0, 1.0, 2.0, 2.5))
    a = MissionRobot(robot_id="a", path=[], breaks=[], track=lawn_track(-4.9, 0.0, -4.9, 4.9, 0.25, seed=1))
    b = MissionRobot(robot_id="b", path=[], breaks=[], track=lawn_track(0.1, 5.0, -4.9, 4.9, 0.25, seed=2))
    assert len(a.track) >= 9_000 and len(b.track) >= 9_000
    coverage = Coverage(rings(box(-5, -5, 5, 5)), [hole], WIDTH)
    for _ in range(20):  # one update per step, each marking at most its budget of points, until all are
        coverage.update([a, b])

    def exact(*tracks: list[list[float]]) -> float:
        return sum(LineString(t).buffer(WIDTH / 2).intersection(region).area for t in tracks)

    strips = LineString(a.track).buffer(WIDTH / 2).union(LineString(b.track).buffer(WIDTH / 2))
    assert coverage.fraction == pytest.approx(strips.intersection(region).area / region.area, abs=0.005)
    assert 0.5 < coverage.fraction < 0.95  # lanes 0.25 m apart at a 0.2 m width: gaps between them
    assert coverage.per_robot["a"] == pytest.approx(exact(a.track), rel=0.01)
    before = coverage.fraction
    for r, point in ((a, [-4.9, 4.99]), (b, [4.9, 4.99])):  # into a corner nobody swept
        r.track.append(point)
        r.track[:-2] = [None] * (len(r.track) - 2)  # unreadable from here on
    coverage.update([a, b])
    assert coverage.work == 2
    assert coverage.fraction > before
    a.track.extend([[-4.9 + 0.02 * i, 4.99] for i in range(1, 11)])
    coverage.update([a, b])
    assert coverage.work == 10  # what a step adds is what it marks, not what the mission has
