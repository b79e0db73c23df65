"""Missions: create (with its plan), start, pause, resume, abort, read with progress, list, coverage GeoJSON.

Viewers read; operators act. Start and resume take the robots' control leases for the mission (it holds
them while it runs); stop-like actions (pause, abort) never need one. Every action is in the audit trail."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, Header, Path, Query, Response

from backend.api.deps import OPERATOR, VIEWER, ActorDep, OperatorDep, ServicesDep
from backend.api.separation import DEFAULT_MIN_SEPARATION_M, separation_of
from backend.schemas.missions import (
    MissionAction,
    MissionCreate,
    MissionEvent,
    MissionPublic,
    MissionResume,
    MissionSummary,
    MissionTransition,
)
from backend.services.missions.raster import swept_png
from backend.services.missions.record import mission_public, mission_summaries

router = APIRouter(prefix="/api/missions", tags=["missions"], dependencies=[VIEWER])

MissionId = Annotated[str, Path(min_length=1, max_length=36, pattern=r"^[A-Za-z0-9_-]+$")]
UNKNOWN: dict[int | str, dict[str, Any]] = {404: {"description": "unknown mission (code unknown_mission)"}}
ACTION: dict[int | str, dict[str, Any]] = {
    **UNKNOWN,
    409: {"description": "not allowed in the mission's state (code bad_mission_state)"},
}
STOPPING: dict[int | str, dict[str, Any]] = {
    **ACTION,
    202: {
        "model": MissionPublic,
        "description": "asked of the replica that runs the mission, not applied within 2.5 s (``requested`` names "
        "the action; that replica applies it, or, if it died, its robots stopped and another takes it over paused)",
    },
}
READY: dict[int | str, dict[str, Any]] = {
    **ACTION,
    422: {"description": "a robot is not ready (code robot_not_ready: the reasons per robot), or invalid parameters"},
    409: {
        "description": "wrong state (bad_mission_state), a robot already in another mission (robot_in_mission), "
        "another operator drives one of its robots (lease_held, naming them), the fleet e-stop is engaged "
        "(estop_engaged), or no site is set to re-plan in (no_site)"
    },
}


@router.post(
    "",
    response_model=MissionPublic,
    status_code=201,
    dependencies=[OPERATOR],
    responses={
        409: {"description": "no site is set (code no_site): a mission plans inside the site"},
        503: {"description": "the planner is busy (code planner_busy; see Retry-After)"},
        422: {
            "description": "a bad field, named in ``detail``: the schema's (validation_error: zero robots, a "
            "sweep width <= 0 ...), robots the server does not know (unknown_robot), a self-intersecting area "
            "(bad_area), an area outside the site (area_outside_site), nothing to sweep (area_empty), more lanes "
            "per robot than a path holds (too_many_lanes) or more planning than allowed (plan_too_large), both "
            "refused before any plan is built (docs/missions.md, Limits), a plan too long for a path "
            "(too_many_waypoints), paths not matching the robots (paths_mismatch) or outside "
            "the fence (outside_site); a formation's leader not among the robots (leader_not_in_mission), "
            "slots not one per follower (slots_mismatch) or closer than the site's minimum separation "
            "(slots_too_close)"
        },
    },
)
async def create_mission(
    services: ServicesDep, principal: OperatorDep, actor: ActorDep, body: Annotated[MissionCreate, Body()]
) -> MissionPublic:
    """A draft mission with its plan (the parts and paths to preview); nothing moves until it is started."""
    mission = await services.missions.create(body, principal.name)
    services.audit.record(actor, "mission_create", None, {"id": mission.id, "type": mission.type})
    return mission


@router.get("", response_model=list[MissionSummary])
async def list_missions(services: ServicesDep) -> list[MissionSummary]:
    """Every mission, newest first."""
    return mission_summaries(list(services.missions.missions.values()))


@router.get("/{mission_id}", response_model=MissionPublic, responses=UNKNOWN)
async def get_mission(services: ServicesDep, mission_id: MissionId) -> MissionPublic:
    """State, per-robot progress, covered fraction (from the robots' actual tracks), elapsed time, ETA, the
    plan, every state transition and the events (dropouts, re-plans, waits for separation); once it ended,
    its report's ``separation``: how close its robots came and how often their safety filters stepped in."""
    mission = services.missions.get(mission_id)
    public = mission_public(mission)
    transitions, events = await services.missions.history(mission_id)
    public.transitions = [MissionTransition.model_validate(t) for t in transitions]
    public.events = [MissionEvent.model_validate(e) for e in events]
    if public.started_at is not None and public.ended_at is not None:  # the report of an ended mission
        min_sep = float(mission.plan.get("min_separation_m", DEFAULT_MIN_SEPARATION_M))
        public.separation = await separation_of(
            services, list(public.robots), public.started_at, public.ended_at, min_sep
        )
    return public


COVERAGE_FORMATS = ("geojson", "png")


@router.get(
    "/{mission_id}/coverage",
    response_class=Response,
    responses={
        **UNKNOWN,
        503: {
            "description": "the planner (which outlines the swept area and draws the PNG) is busy (code "
            "planner_busy; see Retry-After)"
        },
        200: {
            "content": {
                "application/geo+json": {"schema": {"type": "object"}},
                "image/png": {"schema": {"type": "string", "format": "binary"}},
            },
            "description": "the swept area: a GeoJSON geometry, or a PNG (swept green, workable but unswept "
            "grey, outside transparent) georeferenced by X-Fleet-Bounds (minx,miny,maxx,maxy in metres, row 0 at "
            "maxy) and X-Fleet-Resolution-M",
        },
    },
)
async def coverage(
    services: ServicesDep,
    mission_id: MissionId,
    fmt: Annotated[
        Literal["geojson", "png"] | None,
        Query(alias="format", description="geojson or png; none: from Accept (image/png), else geojson"),
    ] = None,
    px_per_m: Annotated[float, Query(gt=0, le=500, description="PNG pixels per metre (lowered to fit 4 Mpx)")] = 100.0,
    accept: Annotated[str, Header()] = "",
) -> Response:
    """The area the robots' tracks swept, clipped to the workable region (from where they actually went, not
    from the plan; at the cells of its grid, an eighth of the sweep width); a finished mission keeps it.
    Outlined and drawn on the planner pool, never on the event loop (docs/missions.md)."""
    services.missions.get(mission_id)  # 404 first
    if fmt is None:
        fmt = "png" if "image/png" in accept and "geo+json" not in accept else "geojson"
    if fmt == "geojson":
        return Response(await services.missions.coverage_geojson(mission_id), media_type="application/geo+json")
    view, fraction = await services.missions.coverage_view(mission_id)
    # on the planner pool, not the threads that serve database reads (up to 4 Mpx: a few hundred ms)
    raster = await services.missions.planner.run(swept_png, view, px_per_m)
    headers = {
        "X-Fleet-Bounds": ",".join(f"{v:.4f}" for v in raster.bounds),
        "X-Fleet-Resolution-M": f"{raster.resolution_m:.6f}",
        "X-Fleet-Covered-Fraction": f"{fraction:.4f}",
        "Cache-Control": "no-store",
    }
    return Response(raster.png, media_type="image/png", headers=headers)


@router.post(
    "/{mission_id}/start",
    response_model=MissionPublic,
    dependencies=[OPERATOR],
    responses={**READY, 503: {"description": "the planner (a coverage plan is re-planned) is busy (planner_busy)"}},
)
async def start(services: ServicesDep, actor: ActorDep, principal: OperatorDep, mission_id: MissionId) -> MissionPublic:
    """draft -> running: every robot must be ready; parts go to the robots by where they are; all first legs
    go out at the same moment."""
    mission = await services.missions.start(mission_id, principal.name, by=actor)
    services.audit.record(actor, "mission_start", None, {"id": mission_id})
    return mission


@router.post("/{mission_id}/pause", response_model=MissionPublic, dependencies=[OPERATOR], responses=STOPPING)
async def pause(
    services: ServicesDep,
    actor: ActorDep,
    principal: OperatorDep,
    mission_id: MissionId,
    response: Response,
    body: Annotated[MissionAction | None, Body()] = None,
) -> MissionPublic:
    """running -> paused: the robots stop (motors off; they drift with the water). Through a replica that does
    not run the mission, the one that does applies it (within about a second; 202 if not within 2.5 s)."""
    mission, applied = await services.missions.pause(mission_id, principal.name, body.reason if body else "")
    services.audit.record(actor, "mission_pause", None, {"id": mission_id, "applied": applied})
    if not applied:
        response.status_code = 202
    return mission


@router.post("/{mission_id}/resume", response_model=MissionPublic, dependencies=[OPERATOR], responses=READY)
async def resume(
    services: ServicesDep,
    actor: ActorDep,
    principal: OperatorDep,
    mission_id: MissionId,
    body: Annotated[MissionResume | None, Body()] = None,
) -> MissionPublic:
    """paused -> running, each robot carrying on from where it is; ``rejoin`` names dropped robots to take
    back (a returning robot rejoins only when an operator says so)."""
    rejoin = body.rejoin if body else []
    mission = await services.missions.resume(mission_id, principal.name, rejoin, by=actor)
    services.audit.record(actor, "mission_resume", None, {"id": mission_id, "rejoin": rejoin})
    return mission


@router.post("/{mission_id}/abort", response_model=MissionPublic, dependencies=[OPERATOR], responses=STOPPING)
async def abort(
    services: ServicesDep,
    actor: ActorDep,
    principal: OperatorDep,
    mission_id: MissionId,
    response: Response,
    body: Annotated[MissionAction | None, Body()] = None,
) -> MissionPublic:
    """draft, running or paused -> aborted: the robots stop. Final. Through a replica that does not run the
    mission, as for pause."""
    mission, applied = await services.missions.abort(mission_id, principal.name, body.reason if body else "")
    services.audit.record(actor, "mission_abort", None, {"id": mission_id, "applied": applied})
    if not applied:
        response.status_code = 202
    return mission
