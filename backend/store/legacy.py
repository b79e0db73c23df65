"""Database operations of the legacy registrations: which robots may speak on the old framework's anonymous
topics (``robots.legacy``, with the command topic each listens on). Run by the writer thread."""

from __future__ import annotations

from collections.abc import Callable

from sqlalchemy import Connection, select, update
from sqlalchemy.dialects import postgresql, sqlite

from backend.models import Robot


def register(robot_id: str, listens_on: str, now: float) -> Callable[[Connection], None]:
    """Mark the robot as one on the old framework (creating its row when the server never saw it)."""

    def op(conn: Connection) -> None:
        values = {"id": robot_id, "legacy": True, "legacy_listens_on": listens_on, "first_seen": now}
        ins = (postgresql.insert(Robot) if conn.dialect.name == "postgresql" else sqlite.insert(Robot)).values(**values)
        changes = {"legacy": True, "legacy_listens_on": listens_on}
        conn.execute(ins.on_conflict_do_update(index_elements=["id"], set_=changes))

    return op


def unregister(robot_id: str) -> Callable[[Connection], None]:
    """The robot no longer speaks on the old topics (it stays in the fleet with its data)."""

    def op(conn: Connection) -> None:
        conn.execute(update(Robot).where(Robot.id == robot_id).values(legacy=False))

    return op


def read_registered() -> Callable[[Connection], dict[str, str]]:
    """Every registered robot on the old framework and the command topic it listens on (``shared``/``own``)."""

    def op(conn: Connection) -> dict[str, str]:
        rows = conn.execute(select(Robot.id, Robot.legacy_listens_on).where(Robot.legacy.is_(True)))
        return {r.id: r.legacy_listens_on for r in rows}

    return op
