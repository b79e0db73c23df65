"""The robot registry."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from starlette.concurrency import run_in_threadpool

from backend.api.deps import ADMIN, VIEWER, ActorDep, AdminDep, RobotDep, ServicesDep
from backend.api.errors import errors
from backend.schemas import RobotForgotten, RobotPublic, StreamStats, TelemetryChoice
from backend.store import repository as repo

router = APIRouter(prefix="/api/robots", tags=["robots"], dependencies=[VIEWER])


@router.get("", response_model=list[RobotPublic])
async def list_robots(services: ServicesDep) -> list[RobotPublic]:
    return services.registry.all_public()


@router.get("/{robot_id}", response_model=RobotPublic, responses={404: {"description": "unknown robot"}})
async def get_robot(robot: RobotDep, services: ServicesDep) -> RobotPublic:
    return services.registry.public(robot)


@router.get("/{robot_id}/streams", response_model=list[StreamStats])
async def robot_streams(robot: RobotDep, services: ServicesDep) -> list[StreamStats]:
    """Stored streams with first/last time and row count, plus seq gap counters since server start: gaps
    detected, and of them open (being repaired), repaired and lost (with their ranges)."""
    stats = await run_in_threadpool(repo.stream_stats, services.engine, robot.id)
    stats = services.registry.merge_stream_stats(robot.id, stats)
    return services.repair.merge_summary(robot.id, stats) if services.repair is not None else stats


@router.delete(
    "/{robot_id}",
    response_model=RobotForgotten,
    dependencies=[ADMIN],
    responses=errors(
        e409="the robot is online (code robot_online): stop its agent first",
        e503="not connected to the broker (code broker_unavailable): its retained status could not be cleared",
    ),
)
async def forget_robot(
    robot: RobotDep,
    services: ServicesDep,
    principal: AdminDep,
    actor: ActorDep,
    telemetry: Annotated[
        TelemetryChoice, Query(description="keep its stored telemetry (default), or delete it with its aggregates")
    ] = "keep",
) -> RobotForgotten:
    """Forget a robot that is gone (admin): out of the fleet list and the database, its retained status (and
    retained streams) cleared on the broker so it does not come back, its telemetry kept or deleted. Its
    commands and events stay. The broker credentials are another matter: ``fleet-server robots remove``."""
    forgotten = await services.forgetter.forget(robot.id, telemetry, principal.subject)
    services.audit.record(actor, "robot_forget", robot.id, {"telemetry": telemetry})
    return forgotten
