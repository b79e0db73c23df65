"""Rehearsal: ``POST /api/missions/{id}/rehearsal`` runs a draft mission (or a paused one, before its resume)
in the simulated twin of the fleet and answers what it predicts (docs/missions.md, "Rehearsal")."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query

from backend.api.deps import OPERATOR, ActorDep, ServicesDep
from backend.api.routes.missions import MissionId
from backend.services.rehearsal import MAX_SEEDS

router = APIRouter(prefix="/api/missions", tags=["missions"], dependencies=[OPERATOR])


@router.post(
    "/{mission_id}/rehearsal",
    responses={
        404: {"description": "unknown mission (code unknown_mission)"},
        409: {
            "description": "the mission is neither a draft nor paused (bad_mission_state), no site (no_site), or "
            "start=last without an earlier rehearsal (no_rehearsal)"
        },
        422: {"description": "a robot of the mission has no position fix yet (no_position)"},
        429: {"description": "a rehearsal of this client is running (rehearsal_running)"},
        503: {"description": "the server's rehearsals are all busy (rehearsals_busy)"},
    },
)
async def rehearse(
    services: ServicesDep,
    actor: ActorDep,
    mission_id: MissionId,
    seeds: Annotated[int, Query(ge=1, le=MAX_SEEDS, description="runs with consecutive seeds: a spread")] = 1,
    seed: Annotated[int | None, Query(ge=0, lt=2**31, description="the first seed (none: a random one)")] = None,
    start: Annotated[
        Literal["now", "last"],
        Query(description="from where the robots are now, or where they were for the latest rehearsal (to repeat it)"),
    ] = "now",
) -> dict[str, Any]:
    """The mission run in the twin from where its robots are now, on virtual time in a process of its own:
    ``{"predicted": {"duration_s", "covered_fraction", "min_separation_m", "fence_violations", "collisions",
    "filter_interventions", "blocked_legs", "per_robot", "tracks"}, "seed", "speed_factor", "took_s"}``; with
    ``seeds`` > 1 also ``spread`` (min, median, max of each figure) and ``runs``; ``start``: each robot's
    [x, y, yaw] it started from. The same seed from the same start gives the same prediction (``start=last``
    repeats the latest rehearsal: the robots drift while they wait). The mission keeps the latest (its run
    records it when it starts)."""
    result = await services.rehearsals.rehearse(mission_id, actor.subject, seeds, seed, start == "last")
    services.audit.record(actor, "mission_rehearse", None, {"id": mission_id, "seeds": result["seeds"]})
    return result
