"""The control lease (one operator drives a robot) and the audit trail."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query

from backend.api.deps import VIEWER, ActorDep, OperatorDep, RobotDep, ServicesDep
from backend.core.security import Role
from backend.schemas import LeaseGrant, LeasePublic
from backend.services.access.audit import Actor

router = APIRouter(prefix="/api", tags=["control"], dependencies=[VIEWER])

_LEASE_ERRORS: dict[int | str, dict[str, Any]] = {
    404: {"description": "unknown robot"},
    409: {"description": "driven by someone else (`lease_held`), or not yours to grant"},
}


@router.get("/robots/{robot_id}/lease", response_model=LeasePublic | None, responses={404: _LEASE_ERRORS[404]})
async def get_lease(robot: RobotDep, services: ServicesDep) -> LeasePublic | None:
    """Who drives the robot now (null: nobody; the first drive takes it)."""
    return services.leases.current(robot.id)


@router.post("/robots/{robot_id}/lease", response_model=LeasePublic, responses=_LEASE_ERRORS)
async def take_control(
    robot: RobotDep,
    services: ServicesDep,
    principal: OperatorDep,
    actor: ActorDep,
    force: Annotated[bool, Query(description="admins: take it over from its holder (audited)")] = False,
) -> LeasePublic:
    """ "Take control": the lease is yours until 60 s after your last drive, or until you release it."""
    if force and not principal.allows(Role.ADMIN):
        raise HTTPException(403, detail="taking control over from another operator needs the admin role")
    return await services.leases.take(robot.id, actor, force=force)  # a ServiceError: the app answers it


@router.delete("/robots/{robot_id}/lease", status_code=204, responses={404: _LEASE_ERRORS[404]})
async def release_control(robot: RobotDep, services: ServicesDep, principal: OperatorDep, actor: ActorDep) -> None:
    await services.leases.release(robot.id, actor)


@router.post("/robots/{robot_id}/lease/request", response_model=LeasePublic, responses=_LEASE_ERRORS)
async def request_control(
    robot: RobotDep, services: ServicesDep, principal: OperatorDep, actor: ActorDep
) -> LeasePublic:
    """Ask the holder for control: their dashboard shows the request with a Grant button."""
    return services.leases.request(robot.id, actor)


@router.post("/robots/{robot_id}/lease/grant", response_model=LeasePublic, responses=_LEASE_ERRORS)
async def grant_control(
    robot: RobotDep, services: ServicesDep, principal: OperatorDep, actor: ActorDep, body: LeaseGrant
) -> LeasePublic:
    """The holder hands the lease to whoever asked (``to_holder`` from the ``lease_request`` message)."""
    to = Actor(subject=body.to_holder, name=body.to_name or body.to_holder, holder=body.to_holder)
    return await services.leases.grant(robot.id, actor, to)
