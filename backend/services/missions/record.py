"""The missions' records and views: the in-memory mission, its database row and API shape, and the planning
of a new mission's parts from the site (backend/services/missions/service.py runs them)."""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from shapely.geometry import Point, Polygon

from backend.core.errors import ServiceError
from backend.schemas.missions import (
    FormationMissionCreate,
    MissionPart,
    MissionPublic,
    MissionRobotProgress,
    MissionSummary,
    WaypointsMissionCreate,
)
from backend.services.fleet.registry import Registry
from backend.services.missions.coverage import PlanError, plan_coverage, workable_region
from backend.services.missions.state import DEFAULT_SPEED_MPS, Coverage, RobotRun, rings, robots_from_plan
from backend.services.missions.state import waypoint_runs as make_waypoint_runs
from fleet_protocol import Site

#: the request field a planner refusal is about (its 422 names it)
_FIELD_OF = {
    "no_robots": "robots",
    "bad_sweep_width": "params.sweep_width_m",
    "bad_overlap": "params.overlap",
    "too_many_waypoints": "params.sweep_width_m",
}
#: the simulated Mollusca's radius: with the geofence margin, the band left out along fences
ROBOT_RADIUS_M = 0.1


@dataclass
class Mission:
    id: str
    name: str
    type: str
    state: str
    robot_ids: list[str]
    params: dict[str, Any]
    created_by: str
    created_at: float
    updated_at: float
    plan: dict[str, Any]
    robots: list[RobotRun]
    coverage: Coverage
    reason: str = ""
    started_at: float | None = None
    ended_at: float | None = None
    run_s: float = 0.0
    running_since: float | None = None
    saved_at: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    #: the server replica that runs it (its row lease); None: none has yet
    owner: str | None = None
    #: pause or abort asked through another replica, not applied yet by the owner
    requested: dict[str, Any] | None = None
    #: the run it opened when it started (recording its robots until it ends); None: none
    run_id: int | None = None

    def robot(self, robot_id: str) -> RobotRun | None:
        return next((r for r in self.robots if r.robot_id == robot_id), None)

    def elapsed(self, now: float) -> float:
        return self.run_s + (now - self.running_since if self.running_since is not None else 0.0)


def plan_coverage_mission(
    site: Site, params: dict[str, Any], robot_ids: list[str], registry: Registry
) -> tuple[dict[str, Any], list[RobotRun]]:
    boundary = Polygon(site.boundary)
    area = Polygon(params["area"]) if params.get("area") else boundary
    if not area.is_valid or area.area <= 0:
        raise ServiceError(422, "params.area: not a simple polygon with an area (self-intersecting?)", "bad_area")
    if not area.within(boundary.buffer(1e-6)):
        raise ServiceError(422, "params.area: reaches outside the site's boundary", "area_outside_site")
    band = site.geofence_margin_m + ROBOT_RADIUS_M
    keepouts = [Polygon(k) for k in site.keepouts]
    region = workable_region(area, boundary, keepouts, band)
    try:
        plan = plan_coverage(region, len(robot_ids), params["sweep_width_m"], params["overlap"], site.min_separation_m)
    except PlanError as exc:
        raise ServiceError(422, f"{_FIELD_OF.get(exc.code, 'params.area')}: {exc}", exc.code) from None
    order = order_robots(robot_ids, plan.angle_rad, registry)
    robots = robots_from_plan(order, plan)
    holes = [[list(c) for c in i.coords] for p in getattr(region, "geoms", [region]) for i in p.interiors]
    data = {
        "workable": rings(region),
        "holes": holes,
        "workable_area_m2": round(region.area, 4),
        "band_m": band,
        "min_separation_m": site.min_separation_m,
        "angle_rad": plan.angle_rad,
    }
    return data, robots


def order_robots(robot_ids: list[str], angle: float, registry: Registry) -> list[str]:
    """Robots in the order of the parts (along the split axis), by where they are: their paths to their
    parts then cross as little as possible. Robots without a position keep their place at the end."""
    c, s = math.cos(angle), math.sin(angle)

    def key(rid: str) -> tuple[int, float]:
        st = registry.get(rid)
        pos = st.position if st is not None else None
        return (1, 0.0) if pos is None else (0, pos.x * c + pos.y * s)

    return sorted(robot_ids, key=key)


def plan_waypoints_mission(site: Site, body: WaypointsMissionCreate) -> tuple[dict[str, Any], list[RobotRun]]:
    paths = body.params.paths
    if set(paths) != set(body.robots):
        raise ServiceError(422, "params.paths: one path per robot of the mission, no others", "paths_mismatch")
    for rid, pts in paths.items():
        _inside_fence(site, pts, f"params.paths.{rid}")
    data = _path_plan(site, min_separation_m=site.min_separation_m)
    return data, make_waypoint_runs({rid: [list(p) for p in paths[rid]] for rid in body.robots})


def plan_formation_mission(site: Site, body: FormationMissionCreate) -> tuple[dict[str, Any], list[RobotRun]]:
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
    runs = [RobotRun(robot_id=p.leader, path=[list(q) for q in p.path], breaks=[len(p.path)])]
    runs += [RobotRun(robot_id=rid, path=[], breaks=[]) for rid in followers]
    return data, runs


def _inside_fence(site: Site, points: Sequence[Sequence[float]], field: str) -> None:
    """Each point inside the site's fence (the boundary less the geofence margin), or a 422 naming it."""
    inside = Polygon(site.boundary).buffer(-site.geofence_margin_m)
    for q in points:
        if not inside.contains(Point(q[0], q[1])):
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


def coverage_of(plan: dict[str, Any], params: dict[str, Any]) -> Coverage:
    return Coverage(plan.get("workable", []), plan.get("holes", []), float(params.get("sweep_width_m", 0.2)))


def mission_row(m: Mission, full: bool = False) -> dict[str, Any]:
    row: dict[str, Any] = {
        "state": m.state,
        "reason": m.reason,
        "updated_at": m.updated_at,
        "started_at": m.started_at,
        "ended_at": m.ended_at,
        "run_s": m.elapsed(time.time()) if m.state == "running" else m.run_s,
        "plan": m.plan,
        "progress": {
            "run_id": m.run_id,
            "robots": [r.to_json() for r in m.robots],
            "covered_fraction": m.coverage.fraction,
            "swept_m2": m.coverage.per_robot,
        },
    }
    if full:
        row.update(
            id=m.id,
            name=m.name,
            type=m.type,
            robots=m.robot_ids,
            params=m.params,
            created_by=m.created_by,
            created_at=m.created_at,
        )
    return row


def mission_public(m: Mission) -> MissionPublic:
    now = time.time()
    speed = float(m.params.get("speed") or DEFAULT_SPEED_MPS)
    left = max((r.remaining_m() for r in m.robots if r.active), default=0.0)
    return MissionPublic(
        id=m.id,
        name=m.name,
        type=m.type,
        state=m.state,  # type: ignore[arg-type]
        reason=m.reason,
        robots=m.robot_ids,
        params=m.params,
        created_by=m.created_by,
        created_at=m.created_at,
        updated_at=m.updated_at,
        started_at=m.started_at,
        ended_at=m.ended_at,
        elapsed_s=round(m.elapsed(now), 2),
        eta_s=round(left / speed, 1) if m.state in ("draft", "running", "paused") else None,
        covered_fraction=round(m.coverage.fraction, 4),
        workable_area_m2=float(m.plan.get("workable_area_m2", 0.0)),
        band_m=float(m.plan.get("band_m", 0.0)),
        replica=m.owner,
        requested=(m.requested or {}).get("action"),
        run_id=m.run_id,
        parts=[
            MissionPart(
                robot_id=r.robot_id,
                polygon=r.polygon,
                path=r.path,
                head_end=r.head_pass,
                tail_start=r.gate_at if r.gate_at is not None else len(r.path),
                area_m2=r.area_m2,
                length_m=round(_length(r.path), 3),
            )
            for r in m.robots
        ],
        progress=[
            MissionRobotProgress(
                robot_id=r.robot_id,
                status=r.status,
                reason=r.reason,
                waypoint_index=max(r.index, r.reached),
                waypoint_count=len(r.path),
                fraction=round(min(1.0, max(r.index, r.reached) / max(1, len(r.path))), 4),
                swept_m2=round(m.coverage.per_robot.get(r.robot_id, 0.0), 4),
            )
            for r in m.robots
        ],
    )


def mission_summaries(missions: list[Mission]) -> list[MissionSummary]:
    return [
        MissionSummary(
            id=m.id,
            name=m.name,
            type=m.type,
            state=m.state,  # type: ignore[arg-type]
            reason=m.reason,
            robots=m.robot_ids,
            created_at=m.created_at,
            covered_fraction=round(m.coverage.fraction, 4),
        )
        for m in sorted(missions, key=lambda m: m.created_at, reverse=True)
    ]


def _length(path: list[list[float]]) -> float:
    return sum(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in itertools.pairwise(path))
