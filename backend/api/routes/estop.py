"""Fleet-wide latched e-stop."""

from __future__ import annotations

import logging

from fastapi import APIRouter

from backend.api.deps import OPERATOR, VIEWER, ActorDep, OperatorDep, ServicesDep, ViewerDep
from backend.core.security import Principal
from backend.schemas import EStopCreate, EStopEngaged, EStopPublic

log = logging.getLogger(__name__)
router = APIRouter(prefix="/api/estop", tags=["estop"], dependencies=[VIEWER])


def _who(principal: Principal, client: str) -> str:
    """The e-stop's ``source`` as the dashboard shows it: who pressed it (from their credentials, not
    from the request body) and the client they named ("ada via ui")."""
    return f"{principal.name} via {client}"[:120]


@router.post("", response_model=EStopEngaged, status_code=202)
async def engage(
    services: ServicesDep, principal: ViewerDep, actor: ActorDep, body: EStopCreate | None = None
) -> EStopEngaged:
    """Publishes a retained e-stop: every robot stops and refuses drive commands until released.
    Any logged-in user may press it (viewers too: whoever sees danger stops the fleet).
    Never rate-limited; audited (``estop``: pressed again while engaged, it is counted in that row)."""
    body = body or EStopCreate()
    log.warning("e-stop pressed by %s (%s)", principal.name, principal.subject)
    return await services.estop.engage(body.reason, _who(principal, body.source), actor, body.source)


@router.post("/release", response_model=EStopEngaged, status_code=202, dependencies=[OPERATOR])
async def release(
    services: ServicesDep, principal: OperatorDep, actor: ActorDep, body: EStopCreate | None = None
) -> EStopEngaged:
    body = body or EStopCreate()
    log.warning("e-stop released by %s (%s)", principal.name, principal.subject)
    return await services.estop.release(body.reason, _who(principal, body.source), actor, body.source)


@router.get("", response_model=EStopPublic)
async def state(services: ServicesDep) -> EStopPublic:
    return services.estop.state
