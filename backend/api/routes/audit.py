"""The audit trail, for admins: who did what (commands, e-stops, holds, lease changes, site, runs, users)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from starlette.concurrency import run_in_threadpool

from backend.api.deps import ADMIN, VIEWER, ServicesDep
from backend.schemas import AuditEntry
from backend.store import audit as store

router = APIRouter(prefix="/api", tags=["audit"], dependencies=[VIEWER])


@router.get("/audit", response_model=list[AuditEntry], dependencies=[ADMIN])
async def audit_trail(
    services: ServicesDep,
    start: Annotated[float | None, Query(description="epoch seconds")] = None,
    end: Annotated[float | None, Query(description="epoch seconds")] = None,
    action: Annotated[str | None, Query(max_length=64)] = None,
    actor: Annotated[str | None, Query(max_length=160, description="subject or name")] = None,
    robot_id: Annotated[str | None, Query(max_length=64)] = None,
    before_id: Annotated[int | None, Query(ge=1, le=2**62, description="page: entries older than this id")] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> list[AuditEntry]:
    """Append-only: commands, e-stops, holds, lease changes, site and user changes; newest first."""
    rows = await run_in_threadpool(
        store.list_audit,
        services.engine,
        start=start,
        end=end,
        action=action,
        actor=actor,
        robot_id=robot_id,
        before_id=before_id,
        limit=limit,
    )
    return [AuditEntry(**r) for r in rows]
