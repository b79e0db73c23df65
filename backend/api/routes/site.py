"""The site the fleet works in (``/api/site``: read by everyone, changed by admins, every version kept) and
the units of the telemetry fields (``GET /api/units``)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query

from backend.api.deps import ADMIN, VIEWER, ActorDep, ServicesDep
from backend.schemas import SitePublic, SiteUpdate, UnitsPublic
from backend.services.site.service import SiteVersion
from fleet_protocol.units import STREAM_UNITS

router = APIRouter(tags=["site"], dependencies=[VIEWER])

CHANGE_RESPONSES: dict[int | str, dict[str, str]] = {
    409: {"description": "changed at the same moment on another server replica (code site_conflict); try again"},
}


def site_public(v: SiteVersion) -> SitePublic:
    common: dict[str, Any] = {
        "version": v.version,
        "source": v.source,
        "updated_by": v.updated_by,
        "updated_at": v.updated_at,
        "avoidance": v.avoidance.model_dump(),
    }
    if v.site is None:
        return SitePublic.model_validate({"boundary": [], "configured": False, **common})
    return SitePublic.model_validate({**v.site.model_dump(), "configured": True, **common})


@router.get("/api/site", response_model=SitePublic)
async def site(services: ServicesDep) -> SitePublic:
    """The current site: what the map draws, what goals are checked against and what robots have (retained
    on ``{prefix}/site``). ``configured`` false: no site, no fence."""
    return site_public(await services.site.latest())


@router.get("/api/site/versions", response_model=list[SitePublic])
async def site_versions(
    services: ServicesDep,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    before: Annotated[int | None, Query(ge=1, le=2**31 - 1, description="versions older than this one")] = None,
) -> list[SitePublic]:
    """Every version of the site, newest first: who set it and when."""
    return [site_public(v) for v in await services.site.versions(limit, before)]


@router.put(
    "/api/site",
    response_model=SitePublic,
    dependencies=[ADMIN],
    responses={
        422: {
            "description": "not a site: invalid numbers or shapes (code validation_error), a polygon that "
            "crosses itself or has no area (bad_polygon), a keep-out not inside the boundary "
            "(keepout_outside_boundary), a tag id twice (duplicate_tag); nothing changed"
        },
        **CHANGE_RESPONSES,
    },
)
async def set_site(body: SiteUpdate, services: ServicesDep, actor: ActorDep) -> SitePublic:
    """A new version of the site (admin, audited). Published retained to every robot at once; goals are
    checked against it from now on. ``avoidance`` omitted: the robots' safety filter keeps its settings."""
    site = body.model_dump(mode="json", exclude={"avoidance"})
    avoidance = None if body.avoidance is None else body.avoidance.model_dump(mode="json")
    return site_public(await services.site.replace(site, actor, avoidance))


@router.delete("/api/site", response_model=SitePublic, dependencies=[ADMIN], responses=CHANGE_RESPONSES)
async def clear_site(services: ServicesDep, actor: ActorDep) -> SitePublic:
    """Set "no site": a new version without a boundary (admin, audited). Robots are told (``site: null``):
    they have no geofence, and the map says so."""
    return site_public(await services.site.replace(None, actor))


@router.get("/api/units", response_model=UnitsPublic)
async def units() -> UnitsPublic:
    """The units of the known streams' data fields (the same table CSV exports name in their header)."""
    return UnitsPublic(streams=STREAM_UNITS)
