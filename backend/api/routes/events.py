"""Event history: online/offline, e-stop and its acks, rejected input."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from starlette.concurrency import run_in_threadpool

from backend.api.deps import VIEWER, ServicesDep
from backend.api.params import EndQ, StartQ, parse_range
from backend.schemas import EventPublic
from backend.store import repository as repo

router = APIRouter(prefix="/api/events", tags=["events"], dependencies=[VIEWER])


@router.get("", response_model=list[EventPublic])
async def list_events(
    services: ServicesDep,
    start: StartQ = None,
    end: EndQ = None,
    kind: Annotated[str | None, Query(max_length=32)] = None,
    robot_id: Annotated[str | None, Query(max_length=64)] = None,
    limit: Annotated[int, Query(ge=1, le=10000)] = 500,
) -> list[EventPublic]:
    """Newest first."""
    lo, hi = parse_range(start, end)
    return await run_in_threadpool(repo.list_events, services.engine, lo, hi, kind, robot_id, limit)
