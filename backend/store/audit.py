"""The audit trail's table: one row per action an actor took, appended through the writer; read newest first."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, Engine, insert, or_, select, update

from backend.models import AuditRow


def insert_audit(values: dict[str, Any]) -> Callable[[Connection], None]:
    def op(conn: Connection) -> None:
        conn.execute(insert(AuditRow).values(**values))

    return op


#: names a coalesced e-stop row keeps of those who engaged it again (the count has them all)
REPEATERS_KEPT = 10


def record_estop(conn: Connection, values: dict[str, Any], repeat: bool) -> None:
    """An e-stop's row (in the latch's store transaction). ``repeat``: an engage while the e-stop was already
    engaged: the newest ``estop`` row counts it (``repeats``, ``last_repeat_at``, ``repeated_by``) instead of a
    row of its own, so a flood of engages is one row. That count is the only thing ever changed in a row."""
    if repeat:
        latest = conn.execute(
            select(AuditRow.id, AuditRow.detail)
            .where(AuditRow.action == "estop")
            .order_by(AuditRow.ts.desc())
            .limit(1)
            .with_for_update()
        ).first()
        if latest is not None:
            detail = dict(latest.detail or {})
            by = list(detail.get("repeated_by") or [])
            if values["actor_name"] not in by and len(by) < REPEATERS_KEPT:
                by.append(values["actor_name"])
            detail.update(repeats=int(detail.get("repeats") or 0) + 1, last_repeat_at=values["ts"], repeated_by=by)
            conn.execute(update(AuditRow).where(AuditRow.id == latest.id).values(detail=detail))
            return
    conn.execute(insert(AuditRow).values(**values))


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
