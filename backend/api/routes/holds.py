"""Per-robot safety: the stop latch ("hold this robot") and the addressing of robots on the old framework."""

from __future__ import annotations

import logging

from fastapi import APIRouter, HTTPException

from backend.api.deps import VIEWER, ActorDep, AdminDep, OperatorDep, RobotDep, ServicesDep, ViewerDep
from backend.schemas import HoldCreate, HoldPublic, LegacyAddressing, RobotPublic

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
    responses={404: {"description": "unknown robot"}},
)
async def release_hold(robot: RobotDep, services: ServicesDep, principal: OperatorDep, actor: ActorDep) -> HoldPublic:
    """Release the robot's hold: drives are accepted again (unless the fleet e-stop is latched)."""
    msg = await services.holds.set(robot.id, False, "", principal.name)
    services.audit.record(actor, "hold_release", robot.id, {})
    return HoldPublic(**msg.model_dump())


@router.put(
    "/{robot_id}/legacy-addressing",
    response_model=RobotPublic,
    responses={404: {"description": "unknown robot"}, 422: {"description": "not a robot on the old framework"}},
)
async def set_legacy_addressing(
    robot: RobotDep, services: ServicesDep, principal: AdminDep, actor: ActorDep, body: LegacyAddressing
) -> RobotPublic:
    """Which command topic a robot on the old framework listens on: ``shared`` (the seed's code,
    ``robot/control/commands``: one drive moves every such robot) or ``own`` (``{id}/control/commands``)."""
    if not robot.legacy:
        raise HTTPException(422, detail=f"robot {robot.id!r} is not on the old framework")
    log.warning("legacy robot %s listens on %s topic (set by %s)", robot.id, body.listens_on, principal.name)
    robot.legacy_listens_on = body.listens_on
    services.registry.persist(robot)
    services.registry.event("legacy_addressing", robot.id, {"listens_on": body.listens_on, "by": principal.name})
    services.audit.record(actor, "legacy_addressing", robot.id, {"listens_on": body.listens_on})
    for st in services.registry.robots.values():  # the shared unit changed for its other members too
        if st.legacy:
            services.registry.push(st)
    return services.registry.public(robot)
