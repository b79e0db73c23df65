"""The control lease (one operator drives a robot) and the audit trail."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query
from starlette.concurrency import run_in_threadpool

from backend.api.deps import OPERATOR, VIEWER, ActorDep, AuthDep, OperatorDep, RobotDep, ServicesDep
from backend.core.errors import ServiceError
from backend.core.security import AUTH_OFF_PRINCIPAL, Role
from backend.schemas import LeaseGrant, LeasePublic
from backend.services.access.audit import Actor

router = APIRouter(prefix="/api", tags=["control"], dependencies=[VIEWER])

_LEASE_ERRORS: dict[int | str, dict[str, Any]] = {
    404: {"description": "unknown robot"},
    409: {
        "description": "driven by someone else (`lease_held`), not yours to grant (`lease_not_yours`), or granted "
        "to no one who may drive (`unknown_holder`)"
    },
}


@router.get("/robots/{robot_id}/lease", response_model=LeasePublic | None, responses={404: _LEASE_ERRORS[404]})
async def get_lease(robot: RobotDep, services: ServicesDep) -> LeasePublic | None:
    """Who drives the robot now (null: nobody; the first drive takes it)."""
    return services.leases.current(robot.id)


@router.post("/robots/{robot_id}/lease", response_model=LeasePublic, dependencies=[OPERATOR], responses=_LEASE_ERRORS)
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


@router.delete(
    "/robots/{robot_id}/lease", status_code=204, dependencies=[OPERATOR], responses={404: _LEASE_ERRORS[404]}
)
async def release_control(robot: RobotDep, services: ServicesDep, principal: OperatorDep, actor: ActorDep) -> None:
    await services.leases.release(robot.id, actor)


@router.post(
    "/robots/{robot_id}/lease/request", response_model=LeasePublic, dependencies=[OPERATOR], responses=_LEASE_ERRORS
)
async def request_control(
    robot: RobotDep, services: ServicesDep, principal: OperatorDep, actor: ActorDep
) -> LeasePublic:
    """Ask the holder for control: their dashboard shows the request with a Grant button."""
    return services.leases.request(robot.id, actor)


@router.post(
    "/robots/{robot_id}/lease/grant", response_model=LeasePublic, dependencies=[OPERATOR], responses=_LEASE_ERRORS
)
async def grant_control(
    robot: RobotDep, services: ServicesDep, auth: AuthDep, principal: OperatorDep, actor: ActorDep, body: LeaseGrant
) -> LeasePublic:
    """The holder hands the lease to whoever asked (``to_holder`` from the ``lease_request`` message). The new
    holder is named as this server knows them (``to_name`` is ignored): the lease, and the audit trail, never
    carry a name a client typed."""
    known = await run_in_threadpool(auth.lease_holder, body.to_holder)
    if known is None or known[1] < Role.OPERATOR:
        raise ServiceError(
            409,
            f"{body.to_holder!r} is no one who may drive (unknown, revoked, disabled or a viewer)",
            "unknown_holder",
        )
    return await services.leases.grant(robot.id, actor, _grantee(body.to_holder, known[0]))


def _grantee(holder: str, name: str) -> Actor:
    """The lease's new holder as ``get_actor`` makes them when they call (with authentication off: a client)."""
    if holder.startswith("client:"):
        return Actor(subject=AUTH_OFF_PRINCIPAL.subject, name=name, holder=holder)
    kind, _, key = holder.partition(":")
    return Actor(subject=holder, name=name, token_id=key if kind == "token" else None)
