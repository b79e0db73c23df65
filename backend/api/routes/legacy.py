"""Robots on the old framework: which may speak on its anonymous topics (registration), and the command
topic each listens on (addressing). Admins only: a registered robot's data is taken from anonymous messages."""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import APIRouter, HTTPException, Path

from backend.api.deps import ADMIN, VIEWER, ActorDep, AdminDep, RobotDep, ServicesDep
from backend.schemas import LegacyAddressing, LegacyRegistration, RobotPublic
from backend.services.legacy.registrations import NotLegacy
from fleet_protocol import ROBOT_ID_PATTERN

log = logging.getLogger(__name__)
router = APIRouter(prefix="/api/robots", tags=["robots"], dependencies=[VIEWER])

RobotIdPath = Annotated[str, Path(pattern=ROBOT_ID_PATTERN, description="the robot's id (its old framework name)")]


@router.put(
    "/{robot_id}/legacy",
    response_model=RobotPublic,
    dependencies=[ADMIN],
    responses={409: {"description": "the robot is online with the agent (the new framework)"}},
)
async def register_legacy_robot(
    robot_id: RobotIdPath,
    services: ServicesDep,
    principal: AdminDep,
    actor: ActorDep,
    body: LegacyRegistration | None = None,
) -> RobotPublic:
    """Register a robot on the old framework: its messages on the old framework's topics (which name the
    robot in the payload, anonymously) are taken from now on; a message naming any robot not registered is
    refused and counted (``legacy_unregistered``). Creates the robot when the server never saw it; again
    with another ``listens_on`` changes its command topic."""
    body = body or LegacyRegistration()
    try:
        st = services.legacy_registrations.register(robot_id, body.listens_on, principal.name)
    except NotLegacy as exc:
        raise HTTPException(409, detail=str(exc)) from None
    services.audit.record(actor, "legacy_register", robot_id, {"listens_on": body.listens_on})
    return services.registry.public(st)


@router.delete(
    "/{robot_id}/legacy",
    response_model=RobotPublic,
    dependencies=[ADMIN],
    responses={404: {"description": "unknown robot"}},
)
async def unregister_legacy_robot(
    robot: RobotDep, services: ServicesDep, principal: AdminDep, actor: ActorDep
) -> RobotPublic:
    """Stop taking the robot's messages on the old framework's topics (it hears ``stop`` first, shows
    offline, and keeps its data): for a robot moved to the agent, or gone."""
    services.legacy_registrations.unregister(robot.id, principal.name)
    services.audit.record(actor, "legacy_unregister", robot.id, {})
    return services.registry.public(robot)


@router.put(
    "/{robot_id}/legacy-addressing",
    response_model=RobotPublic,
    dependencies=[ADMIN],
    responses={404: {"description": "unknown robot"}, 409: {"description": "not a robot on the old framework"}},
)
async def set_legacy_addressing(
    robot: RobotDep, services: ServicesDep, principal: AdminDep, actor: ActorDep, body: LegacyAddressing
) -> RobotPublic:
    """Which command topic a robot on the old framework listens on: ``shared`` (the seed's code,
    ``robot/control/commands``: one drive moves every such robot) or ``own`` (``{id}/control/commands``)."""
    if not robot.legacy:  # the robot's state, not the request's shape: a conflict, as registering it would be
        raise HTTPException(409, detail=f"robot {robot.id!r} is not on the old framework")
    log.warning("legacy robot %s listens on %s topic (set by %s)", robot.id, body.listens_on, principal.name)
    services.legacy_registrations.register(robot.id, body.listens_on, principal.name)
    services.registry.event("legacy_addressing", robot.id, {"listens_on": body.listens_on, "by": principal.name})
    services.audit.record(actor, "legacy_addressing", robot.id, {"listens_on": body.listens_on})
    return services.registry.public(robot)
