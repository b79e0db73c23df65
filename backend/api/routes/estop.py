"""Fleet-wide latched e-stop."""

from __future__ import annotations

import logging

from fastapi import APIRouter

from backend.api.deps import VIEWER, OperatorDep, ServicesDep, ViewerDep
from backend.schemas import EStopCreate, EStopEngaged, EStopPublic

log = logging.getLogger(__name__)
router = APIRouter(prefix="/api/estop", tags=["estop"], dependencies=[VIEWER])


@router.post("", response_model=EStopEngaged, status_code=202)
async def engage(services: ServicesDep, principal: ViewerDep, body: EStopCreate | None = None) -> EStopEngaged:
    """Publishes a retained e-stop: every robot stops and refuses drive commands until released.
    Any logged-in user may press it (viewers too: whoever sees danger stops the fleet).
    Never rate-limited."""
    body = body or EStopCreate()
    log.warning("e-stop pressed by %s (%s)", principal.name, principal.subject)
    return services.estop.engage(body.reason, body.source)


@router.post("/release", response_model=EStopEngaged, status_code=202)
async def release(services: ServicesDep, principal: OperatorDep, body: EStopCreate | None = None) -> EStopEngaged:
    body = body or EStopCreate()
    log.warning("e-stop released by %s (%s)", principal.name, principal.subject)
    return services.estop.release(body.reason, body.source)


@router.get("", response_model=EStopPublic)
async def state(services: ServicesDep) -> EStopPublic:
    return services.estop.state
