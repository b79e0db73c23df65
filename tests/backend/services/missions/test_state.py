"""Re-planning a dropped robot's remaining area (backend/services/missions/state.py), pure geometry."""

from __future__ import annotations

from shapely.geometry import box

from backend.services.missions.coverage import plan_coverage, swept, workable_region
from backend.services.missions.state import Coverage, replan, rings, robots_from_plan

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
