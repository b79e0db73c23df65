"""The audit trail's table: one row per action an actor took, appended through the writer; read newest first."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, Engine, insert, or_, select

from backend.models import AuditRow


def insert_audit(values: dict[str, Any]) -> Callable[[Connection], None]:
    def op(conn: Connection) -> None:
        conn.execute(insert(AuditRow).values(**values))

    return op


def list_audit(
    engine: Engine,
    *,
    start: float | None,
    end: float | None,
    action: str | None,
    actor: str | None,
    robot_id: str | None,
    before_id: int | None,
    limit: int,
) -> list[dict[str, Any]]:
    """Newest first; ``before_id`` pages backwards."""
    stmt = select(AuditRow).order_by(AuditRow.id.desc()).limit(limit)
    if start is not None:
        stmt = stmt.where(AuditRow.ts >= start)
    if end is not None:
        stmt = stmt.where(AuditRow.ts <= end)
    if action:
        stmt = stmt.where(AuditRow.action == action)
    if actor:
        stmt = stmt.where(or_(AuditRow.actor == actor, AuditRow.actor_name == actor))
    if robot_id:
        stmt = stmt.where(AuditRow.robot_id == robot_id)
    if before_id is not None:
        stmt = stmt.where(AuditRow.id < before_id)
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(stmt)]
