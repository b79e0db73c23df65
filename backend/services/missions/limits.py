"""How much work a coverage plan asks for, estimated before any of it is done, and its limits.

A plan's cost grows with its lanes (the area's width across them over the lane spacing) and with the
corners of the region it is cut from (every lane is intersected with it, every cut between two robots is
placed by bisection on it). The schema bounds each number alone (a sweep width only ``> 0``, a site up to
2 km across with 100 keep-outs of 1000 corners), not what they make together: a width of 10 µm over a 4 m
pool asked the planner for 350,000 lanes (40 s of CPU before the waypoint cap refused it). So the lanes
and the work are counted first, in microseconds, from the same geometry the planner would use, and a plan
over either limit is refused with the field, the figure and the limit (docs/missions.md, "Limits").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import shapely
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from backend.services.missions.coverage import MAX_WAYPOINTS, PlanError

#: a lane is two waypoints at least (its two ends): more lanes than this in a robot's part cannot fit
LANES_PER_ROBOT = MAX_WAYPOINTS // 2
#: bisection steps that place one cut between two robots' parts (a micrometre over 2 km: 32)
BISECT_STEPS = 32
#: region corners visited per robot beyond its lanes (its part cut out, grown and prepared, its first lane)
PART_STEPS = 8
#: corners visited, in all: about 1 s of one core of the base station (bench/bench_mission_limits.py)
MAX_PLAN_WORK = 20_000_000


@dataclass(frozen=True)
class CoverageEstimate:
    #: the region's width across the lanes (metres) and the lanes laid over it, in all and per robot
    across_m: float
    lanes: float
    per_robot: float
    #: the corners of the region the lanes are cut from, and the corners visited to plan it (the work)
    corners: int
    work: float


def estimate_coverage(region: BaseGeometry, robots: int, spacing_m: float, corners: int) -> CoverageEstimate:
    """The lanes and the work of planning ``region`` for ``robots`` at ``spacing_m``, as the planner lays
    them: across the long side of the region's minimum rotated rectangle when it is cut between several
    robots, across its short side for one (its lanes then run along the long side)."""
    long_m, short_m = _sides(region)
    across = long_m if robots > 1 else short_m
    lanes = across / spacing_m if spacing_m > 0 else math.inf
    lanes = max(1.0, lanes) if across > 0 else 0.0
    work = corners * (lanes + BISECT_STEPS * (robots - 1) + PART_STEPS * robots)
    return CoverageEstimate(across, lanes, lanes / max(1, robots), corners, work)


def check_coverage(est: CoverageEstimate, sweep_width_m: float, overlap: float, robots: int, work: bool = True) -> None:
    """Refuse (PlanError) a plan over the lane or (``work``) the work limit, saying what would fit."""
    if est.per_robot > LANES_PER_ROBOT:
        spacing = est.across_m / (LANES_PER_ROBOT * robots)
        raise PlanError(
            "too_many_lanes",
            f"a sweep width of {sweep_width_m:.3g} m (overlap {overlap:g}) lays {_count(est.lanes)} lanes across "
            f"the area's {est.across_m:.2f} m, {_count(est.per_robot)} per robot: at most {LANES_PER_ROBOT} per "
            f"robot (each lane is two of a path's {MAX_WAYPOINTS} waypoints); a sweep width of at least "
            f"{spacing / (1 - overlap):.3g} m, a smaller area or more robots fit",
        )
    if work and est.work > MAX_PLAN_WORK:
        raise PlanError(
            "plan_too_large",
            f"{_count(est.lanes)} lanes over a region of {est.corners} corners (the area's, the site boundary's "
            f"and its keep-outs') is {_count(est.work)} steps of planning: at most {MAX_PLAN_WORK:,}; a wider "
            "sweep, fewer robots, a smaller area or fewer keep-out corners fit",
        )


def region_corners(region: BaseGeometry) -> int:
    return int(shapely.get_num_coordinates(region))


def rough_region(area: Polygon, boundary: Polygon, band_m: float) -> tuple[Polygon, int]:
    """What the estimate measures before the workable region is built: the area inside the boundary's inset
    (keep-outs only cut lanes short, they add none), and its corners (the area's and the boundary's).
    Milliseconds, where the region itself takes up to 0.2 s (every keep-out grown and subtracted)."""
    rough = area.intersection(boundary.buffer(-band_m, join_style="mitre"))
    return rough, region_corners(area) + region_corners(boundary)


def keepout_corners(keepouts: list[Polygon], area: Polygon) -> int:
    """The corners the keep-outs that reach the area add to the region."""
    if not keepouts:
        return 0
    near = shapely.intersects(keepouts, area.envelope)
    return sum(region_corners(k) for k, hit in zip(keepouts, near, strict=True) if hit)


def _sides(region: BaseGeometry) -> tuple[float, float]:
    """(long, short) sides of the region's minimum rotated rectangle; (0, 0) for an empty region."""
    if region.is_empty:
        return 0.0, 0.0
    rect = region.minimum_rotated_rectangle
    if not isinstance(rect, Polygon):  # a line or a point: no width
        return float(rect.length), 0.0
    xs, ys = rect.exterior.coords.xy
    a = math.hypot(xs[1] - xs[0], ys[1] - ys[0])
    b = math.hypot(xs[2] - xs[1], ys[2] - ys[1])
    return max(a, b), min(a, b)


def _count(n: float) -> str:
    return f"{n:,.0f}" if n < 1e9 else f"{n:.3g}"
