"""The robot registry."""

from __future__ import annotations

from fastapi import APIRouter
from starlette.concurrency import run_in_threadpool

from backend.api.deps import VIEWER, RobotDep, ServicesDep
from backend.schemas import RobotPublic, StreamStats
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
    """Stored streams with first/last time and row count, plus seq gap counters since server start."""
    stats = await run_in_threadpool(repo.stream_stats, services.engine, robot.id)
    return services.registry.merge_stream_stats(robot.id, stats)
