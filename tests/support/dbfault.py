"""A database that is away: another session holds it, so the server's writes fail fast and are retried (the
writer's outage tests)."""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import Callable, Iterator
from typing import Any

from sqlalchemy import Engine, create_engine, make_url

#: the tables a PostgreSQL blocker locks (SQLite has one lock for the whole file)
LOCKED_TABLES = "telemetry, audit, commands, command_acks, events"


@contextlib.contextmanager
def database_away(database_url: str) -> Iterator[tuple[Engine, Callable[[], None]]]:
    """An engine whose writes fail fast while another session holds the database (SQLite: an exclusive
    transaction; PostgreSQL: the tables locked), and the call that lets go."""
    url = make_url(database_url)
    blocker: Any
    if url.get_backend_name() == "sqlite":
        engine = create_engine(database_url, connect_args={"timeout": 0.05})  # busy: fail fast, then retry
        blocker = sqlite3.connect(str(url.database), isolation_level=None)
        blocker.execute("BEGIN EXCLUSIVE")
        release: Callable[[], Any] = lambda: blocker.execute("ROLLBACK")  # noqa: E731
    else:
        import psycopg

        engine = create_engine(database_url, connect_args={"options": "-c lock_timeout=50"})
        blocker = psycopg.connect(url.set(drivername="postgresql").render_as_string(hide_password=False))
        blocker.execute(f"LOCK TABLE {LOCKED_TABLES} IN ACCESS EXCLUSIVE MODE")
        release = blocker.rollback
    try:
        yield engine, release
    finally:
        blocker.close()
        engine.dispose()
