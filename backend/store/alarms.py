"""Database operations of the alarms (run by the writer thread, or in the thread pool for reads)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, Engine, insert, select, update
from sqlalchemy.dialects import postgresql, sqlite

from backend.models import AlarmRow, AlarmRuleRow, AlarmTransitionRow


def _open(robot_key: str, kind: str) -> Any:
    return (AlarmRow.robot_key == robot_key) & (AlarmRow.kind == kind) & AlarmRow.cleared_at.is_(None)


def raise_alarm(values: dict[str, Any]) -> Callable[[Connection], dict[str, Any]]:
    """Insert an active alarm unless one of that robot and kind is open already (another replica raised it):
    either way, return the open one."""

    def op(conn: Connection) -> dict[str, Any]:
        ins = (postgresql.insert(AlarmRow) if conn.dialect.name == "postgresql" else sqlite.insert(AlarmRow)).values(
            **values
        )
        stmt = ins.on_conflict_do_nothing(
            index_elements=["robot_key", "kind"], index_where=AlarmRow.cleared_at.is_(None)
        )
        # RETURNING, not rowcount: with it PostgreSQL reports -1 for a conflict too (and every replica stored
        # an "active" transition of its own)
        inserted = conn.execute(stmt.returning(AlarmRow.id)).first()
        if inserted is not None:
            conn.execute(
                insert(AlarmTransitionRow).values(
                    alarm_id=inserted.id, ts=values["raised_at"], state="active", by="system"
                )
            )
        row = conn.execute(select(AlarmRow).where(_open(values["robot_key"], values["kind"]))).one()
        return dict(row._mapping)

    return op


def ack_alarm(alarm_id: int, ts: float, by: str) -> Callable[[Connection], dict[str, Any] | None]:
    """Acknowledge an active alarm (an acknowledged or cleared one is left as it is). Returns the row."""

    def op(conn: Connection) -> dict[str, Any] | None:
        done = conn.execute(
            update(AlarmRow)
            .where((AlarmRow.id == alarm_id) & (AlarmRow.state == "active"))
            .values(state="acknowledged", acked_at=ts, acked_by=by)
        ).rowcount
        if done:
            conn.execute(insert(AlarmTransitionRow).values(alarm_id=alarm_id, ts=ts, state="acknowledged", by=by))
        row = conn.execute(select(AlarmRow).where(AlarmRow.id == alarm_id)).one_or_none()
        return dict(row._mapping) if row is not None else None

    return op


def clear_alarm(robot_key: str, kind: str, ts: float, by: str) -> Callable[[Connection], int | None]:
    """Clear the open alarm of that robot and kind; returns its id (None: none was open). Every replica
    clears on the same reading: only the one whose update finds the alarm still open stores the transition
    (the update re-checks ``cleared_at`` under the row's lock)."""

    def op(conn: Connection) -> int | None:
        row = conn.execute(select(AlarmRow.id).where(_open(robot_key, kind))).one_or_none()
        if row is None:
            return None
        done = conn.execute(
            update(AlarmRow)
            .where((AlarmRow.id == row.id) & AlarmRow.cleared_at.is_(None))
            .values(state="cleared", cleared_at=ts)
        ).rowcount
        if not done:
            return None
        conn.execute(insert(AlarmTransitionRow).values(alarm_id=row.id, ts=ts, state="cleared", by=by))
        return int(row.id)

    return op


def override_alarm(alarm_id: int, by: str, ts: float) -> Callable[[Connection], bool]:
    """An admin's override of an open alarm (battery critical: drives allowed again), kept in its ``detail``
    so that every replica reads it. Returns False when the alarm is no longer open."""

    def op(conn: Connection) -> bool:
        row = conn.execute(
            select(AlarmRow.detail).where((AlarmRow.id == alarm_id) & AlarmRow.cleared_at.is_(None))
        ).one_or_none()
        if row is None:
            return False
        detail = {**(row.detail or {}), "override_by": by, "override_at": ts}
        conn.execute(update(AlarmRow).where(AlarmRow.id == alarm_id).values(detail=detail))
        return True

    return op


def read_open() -> Callable[[Connection], list[dict[str, Any]]]:
    """Every open alarm (a replica refreshes its view with it: raises, acks and clears made elsewhere)."""

    def op(conn: Connection) -> list[dict[str, Any]]:
        return [dict(r._mapping) for r in conn.execute(select(AlarmRow).where(AlarmRow.cleared_at.is_(None)))]

    return op


def list_alarms(engine: Engine, state: str | None, limit: int) -> list[dict[str, Any]]:
    stmt = select(AlarmRow).order_by(AlarmRow.id.desc()).limit(limit)
    if state == "open":
        stmt = stmt.where(AlarmRow.cleared_at.is_(None))
    elif state:
        stmt = stmt.where(AlarmRow.state == state)
    with engine.connect() as conn:
        rows = [dict(r._mapping) for r in conn.execute(stmt)]
        ids = [r["id"] for r in rows]
        transitions: dict[int, list[dict[str, Any]]] = {i: [] for i in ids}
        if ids:
            q = select(AlarmTransitionRow).where(AlarmTransitionRow.alarm_id.in_(ids)).order_by(AlarmTransitionRow.id)
            for t in conn.execute(q):
                transitions[t.alarm_id].append({"ts": t.ts, "state": t.state, "by": t.by})
    for r in rows:
        r["transitions"] = transitions[r["id"]]
    return rows


def load_open(engine: Engine) -> list[dict[str, Any]]:
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(select(AlarmRow).where(AlarmRow.cleared_at.is_(None)))]


def load_rules(engine: Engine) -> list[dict[str, Any]]:
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(select(AlarmRuleRow))]


def save_rule(values: dict[str, Any]) -> Callable[[Connection], None]:
    def op(conn: Connection) -> None:
        ins = (
            postgresql.insert(AlarmRuleRow) if conn.dialect.name == "postgresql" else sqlite.insert(AlarmRuleRow)
        ).values(**values)
        conn.execute(
            ins.on_conflict_do_update(
                index_elements=["kind"],
                set_={k: ins.excluded[k] for k in ("enabled", "params", "updated_at", "updated_by")},
            )
        )

    return op
