"""Database operations of the site's versions (run on a worker thread: a site changes rarely, and its writer
must know at once whether its version was stored, so it does not queue behind telemetry in the writer)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, Engine, func, insert, select
from sqlalchemy.exc import IntegrityError

from backend.models import SiteVersionRow
from backend.store.db import write_turn


def latest_site(engine: Engine) -> dict[str, Any] | None:
    """The current version (the newest row), or None before the first start has seeded one."""
    with engine.connect() as conn:
        row = conn.execute(select(SiteVersionRow).order_by(SiteVersionRow.version.desc()).limit(1)).first()
    return None if row is None else dict(row._mapping)


def list_site_versions(engine: Engine, limit: int, before: int | None = None) -> list[dict[str, Any]]:
    """Newest first; ``before`` pages backwards."""
    stmt = select(SiteVersionRow).order_by(SiteVersionRow.version.desc()).limit(limit)
    if before is not None:
        stmt = stmt.where(SiteVersionRow.version < before)
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(stmt)]


def insert_next_site(
    site: dict[str, Any] | None,
    source: str,
    updated_by: str,
    updated_at: float,
    only_if_empty: bool = False,
    avoidance: dict[str, Any] | None = None,
) -> Callable[[Connection], dict[str, Any] | None]:
    """Append the next version (the newest + 1) and return its row. ``only_if_empty``: only when there is no
    version yet (the first start's seed), else None. Two replicas appending at once collide on the primary
    key: the second's transaction fails (IntegrityError) and nothing of it is stored."""

    def op(conn: Connection) -> dict[str, Any] | None:
        newest = conn.execute(select(func.max(SiteVersionRow.version))).scalar()
        if only_if_empty and newest is not None:
            return None
        row = {
            "version": (newest or 0) + 1,
            "site": site,
            "source": source,
            "updated_by": updated_by[:160],
            "updated_at": updated_at,
            "avoidance": avoidance,
        }
        conn.execute(insert(SiteVersionRow).values(**row))
        return row

    return op


class SiteConflict(Exception):
    """Another server replica stored the same version number first: nothing of this one was stored."""


def append_site(
    engine: Engine,
    site: dict[str, Any] | None,
    source: str,
    updated_by: str,
    updated_at: float,
    only_if_empty: bool = False,
    avoidance: dict[str, Any] | None = None,
) -> dict[str, Any] | None:
    """Store the next version in its own transaction (see :func:`insert_next_site`); raises
    :class:`SiteConflict` when another replica's version took the number."""
    try:
        with write_turn(engine), engine.begin() as conn:
            return insert_next_site(site, source, updated_by, updated_at, only_if_empty, avoidance)(conn)
    except IntegrityError as exc:
        raise SiteConflict(str(exc)) from None
