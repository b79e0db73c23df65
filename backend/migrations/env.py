"""Alembic environment. The server passes an open connection in ``config.attributes["connection"]``;
plain ``alembic`` runs build an engine from the server settings."""

from __future__ import annotations

from alembic import context
from sqlalchemy.engine import Connection

from backend.models import Base

target_metadata = Base.metadata


def _run(connection: Connection) -> None:
    context.configure(connection=connection, target_metadata=target_metadata, compare_type=True)
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connection = context.config.attributes.get("connection")
    if connection is not None:
        _run(connection)
        return
    from backend.core.config import Settings
    from backend.store.db import create_db_engine

    engine = create_db_engine(Settings())
    try:
        with engine.connect() as conn:
            _run(conn)
            conn.commit()
    finally:
        engine.dispose()


if context.is_offline_mode():
    raise SystemExit("offline (SQL script) migrations are not supported; use `fleet-server db upgrade`")
run_migrations_online()
