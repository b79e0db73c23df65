"""The coverage planner's promises, as properties over several shapes: the swept strips cover the workable
region, parts are disjoint with equal areas, paths stay inside it (outside the keep-outs), and legs that can
run at the same time keep the minimum separation."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely import affinity
from shapely.geometry import LineString, Point, Polygon, box
from shapely.ops import unary_union

from backend.services.missions.coverage import PlanError, concurrent_clearance, plan_coverage, swept, workable_region

SITE = box(-2, -2, 2, 2)
INSET = 0.25  # geofence margin + robot radius


def wavy(n: int = 200) -> Polygon:
    pts = []
    for i in range(n):
        a = 2 * math.pi * i / n
        r = 1.7 * (1 + 0.08 * math.sin(5 * a))
        pts.append((r * math.cos(a), r * math.sin(a)))
    return Polygon(pts)


CASES = {
    "small square, 3 robots": (box(-0.75, -0.75, 0.75, 0.75), [], 3, 0.25),
    "whole pool, 3 robots": (SITE, [], 3, 0.2),
    "rotated rectangle, 2 robots": (affinity.rotate(box(-1.5, -0.5, 1.5, 0.5), 30), [], 2, 0.2),
    "L shape, 3 robots": (Polygon([(-1.5, -1.5), (1.5, -1.5), (1.5, 0), (0, 0), (0, 1.5), (-1.5, 1.5)]), [], 3, 0.2),
    "200-gon with 3 keep-outs, 10 robots": (
        wavy(),
        [Point(0, 0).buffer(0.3), box(0.8, 0.8, 1.1, 1.2), Point(-1, 0.5).buffer(0.2)],
        10,
        0.2,
    ),
}


def region_of(area: Polygon, keepouts: list[Polygon]) -> Polygon:
    return workable_region(area, SITE, keepouts, INSET)


@pytest.mark.parametrize("name", list(CASES))
def test_plan_covers_fairly_and_stays_inside(name: str) -> None:
    area, keepouts, robots, width = CASES[name]
    region = region_of(area, keepouts)
    plan = plan_coverage(region, robots, width)
    assert len(plan.parts) == robots
    # the whole workable region is swept by the planned paths
    covered = unary_union([swept(p.path, width) for p in plan.parts]).intersection(region).area / region.area
    assert covered >= 0.95, covered
    # parts are disjoint, of equal area, and make up the region
    for i, a in enumerate(plan.parts):
        for b in plan.parts[i + 1 :]:
            assert a.polygon.intersection(b.polygon).area < 1e-6
    mean = region.area / robots
    assert all(abs(p.area_m2 - mean) <= 0.02 * mean for p in plan.parts), [p.area_m2 for p in plan.parts]
    assert abs(sum(p.area_m2 for p in plan.parts) - region.area) < 1e-6
    # paths inside the region: never outside the inset boundary, never into a (grown) keep-out
    inside = region.buffer(1e-6)
    for p in plan.parts:
        assert len(p.path) >= 2
        assert LineString(p.path).within(inside), name
        for k in keepouts:
            assert LineString(p.path).distance(k) >= INSET - 1e-6


@pytest.mark.parametrize("name", ["small square, 3 robots", "whole pool, 3 robots", "rotated rectangle, 2 robots"])
def test_concurrent_legs_keep_min_separation(name: str) -> None:
    area, keepouts, robots, width = CASES[name]
    plan = plan_coverage(region_of(area, keepouts), robots, width, min_separation_m=0.3)
    assert concurrent_clearance(plan) >= 0.3
    # the rule matters: without it (tails running with heads), the neighbours' boundary lanes are closer
    worst = min(
        LineString(a.path).distance(LineString(b.path)) for a, b in zip(plan.parts, plan.parts[1:], strict=False)
    )
    assert worst < 0.3


@settings(max_examples=25, deadline=None)
@given(
    w=st.floats(1.0, 3.5),
    h=st.floats(1.0, 3.5),
    angle=st.floats(0, 180),
    robots=st.integers(1, 4),
    width=st.sampled_from([0.2, 0.25, 0.3]),
)
def test_random_rectangles(w: float, h: float, angle: float, robots: int, width: float) -> None:
    area = affinity.rotate(box(-w / 2, -h / 2, w / 2, h / 2), angle)
    region = region_of(area, [])
    plan = plan_coverage(region, robots, width)
    covered = unary_union([swept(p.path, width) for p in plan.parts]).intersection(region).area / region.area
    assert covered >= 0.95
    assert all(LineString(p.path).within(region.buffer(1e-6)) for p in plan.parts if len(p.path) > 1)
    if robots > 1 and min(p.area_m2 for p in plan.parts) > 0.3:
        assert concurrent_clearance(plan) >= 0.3


def test_lanes_follow_the_long_side() -> None:
    """A 3 m x 1 m strip swept by one robot: lanes run along its length (4 lanes, not 12 across it)."""
    region = box(-1.5, -0.5, 1.5, 0.5)
    plan = plan_coverage(region, 1, 0.25)
    xs = [p[0] for p in plan.parts[0].path]
    assert max(xs) - min(xs) > 2.9
    assert len(plan.parts[0].path) == 8  # 4 lanes of 0.25 m across 1 m, two points each


@pytest.mark.parametrize(
    ("robots", "width", "overlap", "code"),
    [
        (0, 0.2, 0.0, "no_robots"),
        (2, 0.0, 0.0, "bad_sweep_width"),
        (2, -1.0, 0.0, "bad_sweep_width"),
        (2, 0.2, 0.95, "bad_overlap"),
        (2, 0.001, 0.0, "too_many_waypoints"),
    ],
)
def test_bad_requests(robots: int, width: float, overlap: float, code: str) -> None:
    with pytest.raises(PlanError) as err:
        plan_coverage(box(-1, -1, 1, 1), robots, width, overlap)
    assert err.value.code == code


def test_empty_region_refused() -> None:
    region = region_of(box(1.9, 1.9, 3, 3), [])  # only inside the fence's band
    with pytest.raises(PlanError) as err:
        plan_coverage(region, 1, 0.2)
    assert err.value.code == "area_empty"
