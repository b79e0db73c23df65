"""Per-robot safety: the stop latch ("hold this robot")."""

from __future__ import annotations

import logging

from fastapi import APIRouter

from backend.api.deps import OPERATOR, VIEWER, ActorDep, OperatorDep, RobotDep, ServicesDep, ViewerDep
from backend.schemas import HoldCreate, HoldPublic

log = logging.getLogger(__name__)
router = APIRouter(prefix="/api/robots", tags=["robots"], dependencies=[VIEWER])


@router.put(
    "/{robot_id}/hold",
    response_model=HoldPublic,
    responses={404: {"description": "unknown robot"}},
)
async def hold_robot(
    robot: RobotDep, services: ServicesDep, principal: ViewerDep, actor: ActorDep, body: HoldCreate | None = None
) -> HoldPublic:
    """Stop this robot and refuse its drives until released (beside the fleet e-stop). Like the e-stop,
    anyone logged in may hold a robot. Robots on the old framework that share the command topic are one
    unit: holding one refuses drives to all of them."""
    body = body or HoldCreate()
    msg = await services.holds.set(robot.id, True, body.reason, principal.name)
    services.audit.record(actor, "hold", robot.id, {"reason": body.reason})
    if robot.legacy:
        services.legacy_commands.stop(robot)
    else:
        await services.commands.stop_now(robot.id, f"hold by {principal.name}"[:120])
    return HoldPublic(**msg.model_dump())


@router.delete(
    "/{robot_id}/hold",
    response_model=HoldPublic,
    dependencies=[OPERATOR],
    responses={404: {"description": "unknown robot"}},
)
async def release_hold(robot: RobotDep, services: ServicesDep, principal: OperatorDep, actor: ActorDep) -> HoldPublic:
    """Release the robot's hold: drives are accepted again (unless the fleet e-stop is latched)."""
    msg = await services.holds.set(robot.id, False, "", principal.name)
    services.audit.record(actor, "hold_release", robot.id, {})
    return HoldPublic(**msg.model_dump())
