"""Database operations of the missions (the writer thread runs the writes; reads run in the thread pool)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, Engine, insert, or_, select, update

from backend.models import MissionEventRow, MissionRow, MissionTransitionRow

Op = Callable[[Connection], Any]


def insert_mission(values: dict[str, Any], transition: dict[str, Any]) -> Op:
    def op(conn: Connection) -> None:
        conn.execute(insert(MissionRow).values(**values))
        conn.execute(insert(MissionTransitionRow).values(**transition))

    return op


def update_mission(
    mission_id: str, values: dict[str, Any], transition: dict[str, Any] | None = None, owner: str | None = None
) -> Op:
    """Save the mission's changed columns and, with a state change, its transition (one transaction). With
    ``owner``: only while the row is that replica's (or no replica's): a replica that lost the mission to
    another (its lease lapsed) writes nothing over it."""

    def op(conn: Connection) -> bool:
        where = [MissionRow.id == mission_id]
        if owner is not None:
            where.append(or_(MissionRow.owner == owner, MissionRow.owner.is_(None)))
        if conn.execute(update(MissionRow).where(*where).values(**values)).rowcount != 1:
            return False
        if transition is not None:
            conn.execute(insert(MissionTransitionRow).values(**transition))
        return True

    return op


def claim(
    mission_id: str,
    owner: str,
    now: float,
    lease_s: float,
    from_states: tuple[str, ...],
    values: dict[str, Any],
    transition: dict[str, Any] | None = None,
    from_owner: str | None = None,
) -> Op:
    """Compare and set: the row becomes ``owner``'s (with ``values``, e.g. its new state, and the transition)
    only if it is in one of ``from_states`` and no other replica runs it: not running, or running under no
    owner, this one, or one whose heartbeat is older than ``lease_s``. ``from_owner``: only from that owner
    (a takeover). True when this replica got it."""

    def op(conn: Connection) -> bool:
        free = or_(
            MissionRow.state != "running",
            MissionRow.owner.is_(None),
            MissionRow.owner == owner,
            MissionRow.heartbeat_at.is_(None),
            MissionRow.heartbeat_at < now - lease_s,
        )
        where = [MissionRow.id == mission_id, MissionRow.state.in_(from_states), free]
        if from_owner is not None:
            where.append(MissionRow.owner == from_owner)
        done = conn.execute(update(MissionRow).where(*where).values(owner=owner, heartbeat_at=now, **values))
        if done.rowcount != 1:
            return False
        if transition is not None:
            conn.execute(insert(MissionTransitionRow).values(**transition))
        return True

    return op


def renew(owner: str, mission_ids: list[str], now: float) -> Op:
    """The owner's heartbeat on its running missions; returns the ids still its own (the others were taken
    over while it was silent), each with the action another replica asked for (or None)."""

    def op(conn: Connection) -> dict[str, dict[str, Any] | None]:
        mine = [MissionRow.id.in_(mission_ids), MissionRow.owner == owner, MissionRow.state == "running"]
        conn.execute(update(MissionRow).where(*mine).values(heartbeat_at=now))
        return {r[0]: r[1] for r in conn.execute(select(MissionRow.id, MissionRow.requested).where(*mine))}

    return op


def request(mission_id: str, owner: str, action: dict[str, Any]) -> Op:
    """Ask the replica that runs the mission to apply ``action`` (pause, abort): only while it still runs it
    under that owner. True when recorded (an abort is not replaced by a later pause)."""

    def op(conn: Connection) -> bool:
        where = [MissionRow.id == mission_id, MissionRow.state == "running", MissionRow.owner == owner]
        row = conn.execute(select(MissionRow.requested).where(*where)).first()
        if row is None:
            return False
        if row[0] and row[0].get("action") == "abort":
            return True
        return bool(conn.execute(update(MissionRow).where(*where).values(requested=action)).rowcount == 1)

    return op


def orphaned(engine: Engine, owner: str, now: float, lease_s: float) -> list[dict[str, Any]]:
    """Running missions of another replica (or of none) whose heartbeat is older than ``lease_s``."""
    with engine.connect() as conn:
        rows = conn.execute(
            select(MissionRow.id, MissionRow.owner, MissionRow.heartbeat_at).where(
                MissionRow.state == "running",
                or_(MissionRow.owner.is_(None), MissionRow.owner != owner),
                or_(MissionRow.heartbeat_at.is_(None), MissionRow.heartbeat_at < now - lease_s),
            )
        )
        return [dict(r._mapping) for r in rows]


def load_changed(engine: Engine, since: float, running_here: str) -> list[dict[str, Any]]:
    """Missions whose row changed at or after ``since`` (another replica's work, to mirror), except those
    that replica ``running_here`` runs (it holds them in memory)."""
    not_mine = or_(MissionRow.state != "running", MissionRow.owner.is_(None), MissionRow.owner != running_here)
    with engine.connect() as conn:
        query = select(MissionRow).where(MissionRow.updated_at >= since, not_mine).order_by(MissionRow.created_at)
        return [dict(r._mapping) for r in conn.execute(query)]


def load_one(engine: Engine, mission_id: str) -> dict[str, Any] | None:
    with engine.connect() as conn:
        row = conn.execute(select(MissionRow).where(MissionRow.id == mission_id)).first()
        return dict(row._mapping) if row is not None else None


def insert_event(values: dict[str, Any]) -> Op:
    def op(conn: Connection) -> None:
        conn.execute(insert(MissionEventRow).values(**values))

    return op


def load_missions(engine: Engine) -> list[dict[str, Any]]:
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(select(MissionRow).order_by(MissionRow.created_at))]


def history(engine: Engine, mission_id: str, limit: int = 500) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The mission's transitions and its latest events, oldest first."""
    with engine.connect() as conn:
        return history_on(conn, mission_id, limit)


def history_on(
    conn: Connection, mission_id: str, limit: int = 500
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """:func:`history` on a given connection (the writer's: in order with the writes queued before it)."""
    transitions = conn.execute(
        select(MissionTransitionRow)
        .where(MissionTransitionRow.mission_id == mission_id)
        .order_by(MissionTransitionRow.id)
    )
    t = [dict(r._mapping) for r in transitions]
    events = conn.execute(
        select(MissionEventRow)
        .where(MissionEventRow.mission_id == mission_id)
        .order_by(MissionEventRow.id.desc())
        .limit(limit)
    )
    e = [dict(r._mapping) for r in events]
    return t, list(reversed(e))
