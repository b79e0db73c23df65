"""Database operations of the control lease and the audit trail (run by the writer thread)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, case, delete, or_, select
from sqlalchemy.dialects import postgresql, sqlite

from backend.models import LeaseRow

LeaseRowDict = dict[str, Any]


def _upsert(
    conn: Connection,
    robot_id: str,
    holder: str,
    holder_name: str,
    now: float,
    lapse_s: float,
    via: str,
    force: bool,
    also_from: str | None = None,
) -> tuple[LeaseRowDict | None, LeaseRowDict]:
    """Take or renew one lease unless another holder drove within ``lapse_s`` (``force``: take it anyway;
    ``also_from``: a holder whose lease passes to this one, as an operator's to the mission they start).
    Returns the row before (read under a row lock where the database has them) and after the attempt."""
    found = conn.execute(select(LeaseRow).where(LeaseRow.robot_id == robot_id).with_for_update()).one_or_none()
    before = dict(found._mapping) if found is not None else None
    ins = (postgresql.insert(LeaseRow) if conn.dialect.name == "postgresql" else sqlite.insert(LeaseRow)).values(
        robot_id=robot_id, holder=holder, holder_name=holder_name, acquired_at=now, last_drive=now, via=via
    )
    same = LeaseRow.holder == ins.excluded.holder
    passes = [same, LeaseRow.last_drive < now - lapse_s]
    if also_from is not None:
        passes.append(LeaseRow.holder == also_from)
    condition = None if force else or_(*passes)
    update: dict[str, Any] = {
        "holder": ins.excluded.holder,
        "holder_name": ins.excluded.holder_name,
        "last_drive": ins.excluded.last_drive,
        "via": ins.excluded.via,
    }
    if not force:  # a renewal keeps the time it was first taken
        update["acquired_at"] = case((same, LeaseRow.acquired_at), else_=ins.excluded.acquired_at)
    else:
        update["acquired_at"] = ins.excluded.acquired_at
    conn.execute(ins.on_conflict_do_update(index_elements=["robot_id"], set_=update, where=condition))
    row = conn.execute(select(LeaseRow).where(LeaseRow.robot_id == robot_id)).one()
    return before, dict(row._mapping)


def acquire_lease(
    robot_id: str, holder: str, holder_name: str, now: float, lapse_s: float, via: str, force: bool
) -> Callable[[Connection], tuple[LeaseRowDict | None, LeaseRowDict]]:
    """Take or renew the lease unless another holder drove within ``lapse_s`` (``force``: take it anyway).
    Returns the row before and after the attempt: the latter's ``holder`` says who won, the former whom it
    was taken from (the audit trail's takeover is decided here, not from a replica's memory)."""

    def op(conn: Connection) -> tuple[LeaseRowDict | None, LeaseRowDict]:
        return _upsert(conn, robot_id, holder, holder_name, now, lapse_s, via, force)

    return op


class LeaseConflict(Exception):
    """Raised inside :func:`acquire_leases` to roll every lease of the batch back (another replica's holder
    got a robot between the check and the write)."""


def acquire_leases(
    robot_ids: list[str], holder: str, holder_name: str, now: float, lapse_s: float, via: str, also_from: str
) -> Callable[[Connection], tuple[list[tuple[LeaseRowDict | None, LeaseRowDict]], LeaseRowDict | None]]:
    """Take the leases of several robots at once, all or none (a mission's robots). A robot another holder
    drives (not ``also_from``, whose leases pass over) leaves every lease as it was; returns (taken, None) or
    ([], the refusing robot's row)."""

    def op(conn: Connection) -> tuple[list[tuple[LeaseRowDict | None, LeaseRowDict]], LeaseRowDict | None]:
        rows = conn.execute(
            select(LeaseRow).where(LeaseRow.robot_id.in_(robot_ids)).order_by(LeaseRow.robot_id).with_for_update()
        ).all()
        for r in rows:
            if r.holder not in (holder, also_from) and r.last_drive >= now - lapse_s:
                return [], dict(r._mapping)
        taken = [_upsert(conn, rid, holder, holder_name, now, lapse_s, via, False, also_from) for rid in robot_ids]
        if any(after["holder"] != holder for _, after in taken):
            raise LeaseConflict(f"a lease of {robot_ids} was taken meanwhile")  # rolls the batch back
        return taken, None

    return op


def release_lease(robot_id: str, holder: str | None) -> Callable[[Connection], int]:
    """Delete the lease (``holder`` None: whoever holds it). Returns how many rows went."""

    def op(conn: Connection) -> int:
        stmt = delete(LeaseRow).where(LeaseRow.robot_id == robot_id)
        if holder is not None:
            stmt = stmt.where(LeaseRow.holder == holder)
        return int(conn.execute(stmt).rowcount or 0)

    return op


def load_leases() -> Callable[[Connection], list[LeaseRowDict]]:
    """Every lease row (a replica refreshes its view with it: takeovers and releases made elsewhere)."""

    def op(conn: Connection) -> list[LeaseRowDict]:
        return [dict(r._mapping) for r in conn.execute(select(LeaseRow))]

    return op


def release_leases_of(holder: str) -> Callable[[Connection], list[str]]:
    def op(conn: Connection) -> list[str]:
        robots = [r for (r,) in conn.execute(select(LeaseRow.robot_id).where(LeaseRow.holder == holder))]
        conn.execute(delete(LeaseRow).where(LeaseRow.holder == holder))
        return robots

    return op
