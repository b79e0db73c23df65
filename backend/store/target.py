"""Which database a CLI command writes to, and whether it is the server's.

``fleet-server users add`` once wrote to ``./data/fleet.db`` of whatever directory it ran in, printed
success, and the login then failed: the server used another database. The CLI now names the database it
uses and refuses one that FLEET_DATABASE_URL does not name, or that holds no server schema (a server has
never run with it), unless the operator says ``--force``.
"""

from __future__ import annotations

from pathlib import Path

from sqlalchemy import Engine, make_url

from backend.core.config import Settings


class TargetDatabaseError(Exception):
    """The database is probably not the server's; the message says why and what to do."""


def describe_database(settings: Settings) -> str:
    """The database as a person can check it: SQLite as its absolute file path, others without password."""
    url = make_url(settings.database_url)
    if url.get_backend_name() == "sqlite" and url.database and url.database != ":memory:":
        return f"SQLite file {Path(url.database).expanduser().resolve()}"
    return settings.database_url_redacted


def _sqlite_file(settings: Settings) -> Path | None:
    url = make_url(settings.database_url)
    if url.get_backend_name() != "sqlite" or not url.database or url.database == ":memory:":
        return None
    return Path(url.database).expanduser().resolve()


def check_named(settings: Settings, *, force: bool) -> None:
    """Refuse the built-in default database (relative to the current directory) unless forced."""
    if force or "database_url" in settings.model_fields_set:
        return
    raise TargetDatabaseError(
        "FLEET_DATABASE_URL is not set, so this would use the default database, "
        f"{describe_database(settings)} (relative to the current directory), which the server may not use. "
        "Set FLEET_DATABASE_URL to the server's database (as in the server's environment or .env), "
        "or pass --force to use this one anyway."
    )


def check_schema(settings: Settings, engine: Engine, *, force: bool) -> None:
    """Refuse a database without the server's schema (a server never ran with it) unless forced."""
    from backend.store.db import current_revision

    if force:
        return
    path = _sqlite_file(settings)
    if path is not None and not path.exists():
        missing = "does not exist"
    elif current_revision(engine) is None:
        missing = "holds no server schema"
    else:
        return
    raise TargetDatabaseError(
        f"{describe_database(settings)} {missing}: no fleet server has run with it. Check FLEET_DATABASE_URL "
        "(it must name the server's database), or pass --force to create the schema and write there anyway."
    )
