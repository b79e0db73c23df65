"""Planning a mission when it is created (and a coverage mission again when it starts): coverage parts for
the robots by where they are, waypoint paths and formations checked against the fence.

A coverage plan comes in two steps: :func:`check_coverage_mission` refuses what it can before any plan is
built (on the event loop, milliseconds: the limits of limits.py), then :func:`plan_coverage_mission` builds
it on the mission service's planner pool. Nothing here touches the registry from the planner's thread: the
robots' positions are read on the loop first (:func:`positions_of`)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely
from shapely.geometry import Polygon

from backend.core.errors import ServiceError
from backend.schemas.missions import (
    FormationMissionCreate,
    WaypointsMissionCreate,
)
from backend.services.fleet.registry import Registry
from backend.services.missions.coverage import PlanError, plan_coverage, workable_region
from backend.services.missions.limits import (
    check_coverage,
    estimate_coverage,
    keepout_corners,
    rough_region,
)
from backend.services.missions.state import MissionRobot, rings, robots_from_plan, waypoint_robots
from fleet_protocol import Site

#: the request field a planner refusal is about (its 422 names it)
_FIELD_OF = {
    "no_robots": "robots",
    "bad_sweep_width": "params.sweep_width_m",
    "bad_overlap": "params.overlap",
    "too_many_waypoints": "params.sweep_width_m",
    "too_many_lanes": "params.sweep_width_m",
    "plan_too_large": "params.sweep_width_m",
}

#: the simulated Mollusca's radius: with the geofence margin, the band left out along fences
ROBOT_RADIUS_M = 0.1

#: where each robot of a mission is now (None: no position yet), read on the event loop for the planner
Positions = dict[str, tuple[float, float] | None]


@dataclass(frozen=True)
class CoverageJob:
    """A coverage plan whose area and lanes passed (on the event loop, in milliseconds), to build on the
    planner pool."""

    site: Site
    area: Polygon
    boundary: Polygon
    #: the area inside the boundary's inset, and its corners (limits.rough_region)
    rough: Polygon
    corners: int
    band_m: float
    sweep_width_m: float
    overlap: float
    robots: int


def check_coverage_mission(site: Site, params: dict[str, Any], robots: int) -> CoverageJob:
    """What can be refused of a coverage plan before any work: the area, and its lanes against the limit
    (limits.py). Milliseconds: the area and the boundary's inset only (a site's keep-outs may have 100,000
    corners: they are read on the planner, :func:`plan_coverage_mission`)."""
    boundary = Polygon(site.boundary)
    area = Polygon(params["area"]) if params.get("area") else boundary
    if not area.is_valid or area.area <= 0:
        raise ServiceError(422, "params.area: not a simple polygon with an area (self-intersecting?)", "bad_area")
    if not area.within(boundary.buffer(1e-6)):
        raise ServiceError(422, "params.area: reaches outside the site's boundary", "area_outside_site")
    band = site.geofence_margin_m + ROBOT_RADIUS_M
    width, overlap = float(params["sweep_width_m"]), float(params["overlap"])
    rough, corners = rough_region(area, boundary, band)
    try:
        if robots < 1:
            raise PlanError("no_robots", "a coverage mission needs at least one robot")
        lanes = estimate_coverage(rough, robots, width * (1.0 - overlap), corners)
        check_coverage(lanes, width, overlap, robots, work=False)
    except PlanError as exc:
        raise _refusal(exc) from None
    return CoverageJob(site, area, boundary, rough, corners, band, width, overlap, robots)


def plan_coverage_mission(
    job: CoverageJob, robot_ids: list[str], positions: Positions
) -> tuple[dict[str, Any], list[MissionRobot]]:
    """The plan (on the planner pool): its work against the limit first, with the keep-outs that reach the
    area counted, then the workable region and the parts (up to about a second within the limits)."""
    site, spacing = job.site, job.sweep_width_m * (1.0 - job.overlap)
    try:
        keepouts = [Polygon(k) for k in site.keepouts]
        corners = job.corners + keepout_corners(keepouts, job.area)
        check_coverage(
            estimate_coverage(job.rough, job.robots, spacing, corners), job.sweep_width_m, job.overlap, job.robots
        )
        region = workable_region(job.area, job.boundary, keepouts, job.band_m)
        plan = plan_coverage(region, len(robot_ids), job.sweep_width_m, job.overlap, site.min_separation_m)
    except PlanError as exc:
        raise _refusal(exc) from None
    order = order_robots(robot_ids, plan.angle_rad, positions)
    robots = robots_from_plan(order, plan)
    holes = [[list(c) for c in i.coords] for p in getattr(region, "geoms", [region]) for i in p.interiors]
    data = {
        "workable": rings(region),
        "holes": holes,
        "workable_area_m2": round(region.area, 4),
        "band_m": job.band_m,
        "min_separation_m": site.min_separation_m,
        "angle_rad": plan.angle_rad,
    }
    return data, robots


def _refusal(exc: PlanError) -> ServiceError:
    return ServiceError(422, f"{_FIELD_OF.get(exc.code, 'params.area')}: {exc}", exc.code)


def positions_of(robot_ids: list[str], registry: Registry) -> Positions:
    """Where each robot is now (read on the loop: the planner's thread never touches the registry)."""
    out: Positions = {}
    for rid in robot_ids:
        st = registry.get(rid)
        out[rid] = (st.position.x, st.position.y) if st is not None and st.position is not None else None
    return out


def order_robots(robot_ids: list[str], angle: float, positions: Positions) -> list[str]:
    """Robots in the order of the parts (along the split axis), by where they are: their paths to their
    parts then cross as little as possible. Robots without a position keep their place at the end."""
    c, s = math.cos(angle), math.sin(angle)

    def key(rid: str) -> tuple[int, float]:
        pos = positions.get(rid)
        return (1, 0.0) if pos is None else (0, pos[0] * c + pos[1] * s)

    return sorted(robot_ids, key=key)


def plan_waypoints_mission(site: Site, body: WaypointsMissionCreate) -> tuple[dict[str, Any], list[MissionRobot]]:
    paths = body.params.paths
    if set(paths) != set(body.robots):
        raise ServiceError(422, "params.paths: one path per robot of the mission, no others", "paths_mismatch")
    for rid, pts in paths.items():
        _inside_fence(site, pts, f"params.paths.{rid}")
    data = _path_plan(site, min_separation_m=site.min_separation_m)
    return data, waypoint_robots({rid: [list(p) for p in paths[rid]] for rid in body.robots})


def plan_formation_mission(site: Site, body: FormationMissionCreate) -> tuple[dict[str, Any], list[MissionRobot]]:
    """The leader's path (inside the fence) and the followers' slots (one per other robot, apart)."""
    p = body.params
    if p.leader not in body.robots:
        raise ServiceError(
            422, f"params.leader: {p.leader!r} is not one of the mission's robots", "leader_not_in_mission"
        )
    followers = [rid for rid in body.robots if rid != p.leader]
    if set(p.slots) != set(followers):
        raise ServiceError(
            422, "params.slots: one slot per robot of the mission except the leader, no others", "slots_mismatch"
        )
    _inside_fence(site, p.path, "params.path")
    # the slots keep the robots apart as the leader's frame sees them (the followers hold them to centimetres)
    spots = {p.leader: (0.0, 0.0), **{rid: (float(o[0]), float(o[1])) for rid, o in p.slots.items()}}
    for (a, pa), (b, pb) in itertools.combinations(spots.items(), 2):
        if math.dist(pa, pb) < site.min_separation_m:
            raise ServiceError(
                422,
                f"params.slots: {a} and {b} would be {math.dist(pa, pb):.2f} m apart, under the site's minimum "
                f"separation of {site.min_separation_m:g} m",
                "slots_too_close",
            )
    data = _path_plan(site, formation={"leader": p.leader, "slots": {rid: list(spots[rid]) for rid in followers}})
    runs = [MissionRobot(robot_id=p.leader, path=[list(q) for q in p.path], breaks=[len(p.path)])]
    runs += [MissionRobot(robot_id=rid, path=[], breaks=[]) for rid in followers]
    return data, runs


def _inside_fence(site: Site, points: Sequence[Sequence[float]], field: str) -> None:
    """Each point inside the site's fence (the boundary less the geofence margin), or a 422 naming it. The
    points are tested at once against the prepared fence (10,000 points: milliseconds)."""
    inside = Polygon(site.boundary).buffer(-site.geofence_margin_m)
    shapely.prepare(inside)
    xy = np.asarray([[q[0], q[1]] for q in points], dtype=float).reshape(-1, 2)
    ok = shapely.contains_xy(inside, xy[:, 0], xy[:, 1])
    if not ok.all():
        q = points[int(np.argmin(ok))]
        raise ServiceError(422, f"{field}: {list(q)} is outside the site's fence", "outside_site")


def _path_plan(site: Site, **extra: Any) -> dict[str, Any]:
    """The plan of a mission that follows given paths: no area to sweep, the band it keeps off the fence."""
    return {
        "workable": [],
        "holes": [],
        "workable_area_m2": 0.0,
        "band_m": site.geofence_margin_m + ROBOT_RADIUS_M,
        **extra,
    }
