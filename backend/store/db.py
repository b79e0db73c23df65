"""Engine creation (SQLite pragmas, psycopg 3 for PostgreSQL) and Alembic migrations."""

from __future__ import annotations

import contextlib
import logging
import threading
import time
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from sqlalchemy import Connection, Engine, create_engine, event, make_url

from backend.core.config import Settings

log = logging.getLogger(__name__)

ALEMBIC_INI = Path(__file__).resolve().parents[1] / "alembic.ini"

#: engine -> the lock its in-process SQLite writers take turns on (see write_turn)
_WRITE_GATES: weakref.WeakKeyDictionary[Engine, threading.Lock] = weakref.WeakKeyDictionary()
_GATES_LOCK = threading.Lock()


@contextlib.contextmanager
def write_turn(bind: Engine | Connection, yield_after: bool = False) -> Iterator[None]:
    """Hold around a write transaction of the server's own threads (telemetry writer, rollup, retention).

    SQLite has one writer at a time. Left to SQLite, a writer that finds the database locked waits in its
    busy handler, which polls with sleeps growing to 100 ms: the rollup's back-to-back chunk transactions
    kept the telemetry writer waiting up to 1.2 s, long enough to fill the broker's in-flight window and
    stall the live data of the whole fleet. Here they queue on a lock instead and get the database the
    moment it is free. ``yield_after``: a background job (rollup) sleeps a millisecond after its turn so
    a waiting writer gets the next one. Other databases lock rows, not the database: no gate."""
    engine = bind.engine
    if engine.dialect.name != "sqlite":
        yield
        return
    with _GATES_LOCK:
        gate = _WRITE_GATES.get(engine)
        if gate is None:
            gate = _WRITE_GATES[engine] = threading.Lock()
    with gate:
        yield
    if yield_after:
        time.sleep(0.001)


def _sqlite_pragmas(synchronous: str) -> Any:
    """WAL lets readers run while the writer thread commits. synchronous=NORMAL with WAL: a crashed
    server loses nothing committed, a power cut may lose the last commits (FULL: fsync per commit)."""

    def apply(dbapi_conn: Any, _record: Any) -> None:
        cur = dbapi_conn.cursor()
        cur.execute("PRAGMA journal_mode=WAL")
        cur.execute(f"PRAGMA synchronous={'FULL' if synchronous == 'FULL' else 'NORMAL'}")
        cur.execute("PRAGMA busy_timeout=5000")  # the rollup job and the writer take turns
        cur.execute("PRAGMA journal_size_limit=67108864")  # the WAL shrinks back to 64 MB after checkpoints
        cur.close()

    return apply


def create_db_engine(settings: Settings) -> Engine:
    url = make_url(settings.database_url)
    if url.get_backend_name() == "sqlite":
        if url.database and url.database != ":memory:":
            Path(url.database).expanduser().parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(url, connect_args={"check_same_thread": False}, pool_size=8, max_overflow=8)
        event.listen(engine, "connect", _sqlite_pragmas(settings.sqlite_synchronous))
        return engine
    return create_engine(url, pool_size=8, max_overflow=8, pool_pre_ping=True)


def _sqlite_statement_timeout(engine: Engine, timeout_s: float) -> None:
    """SQLite has no statement timeout: a progress handler interrupts a statement (execution and fetch)
    that runs past its deadline, so no reader holds a snapshot, and with it the WAL, for longer."""

    def connected(dbapi_conn: Any, record: Any) -> None:
        deadline = record.info.setdefault("deadline", [0.0])
        dbapi_conn.set_progress_handler(lambda: int(0.0 < deadline[0] < time.monotonic()), 10_000)

    def executing(conn: Connection, *_args: Any) -> None:
        conn.info["deadline"][0] = time.monotonic() + timeout_s

    def checked_in(_dbapi_conn: Any, record: Any) -> None:
        if "deadline" in record.info:
            record.info["deadline"][0] = 0.0

    event.listen(engine, "connect", connected)
    event.listen(engine, "before_cursor_execute", executing)
    event.listen(engine.pool, "checkin", checked_in)


def create_reader_engine(settings: Settings) -> Engine:
    """The readers' own small pool (history reads and exports): however many readers wait, the writer,
    leases, audit and health keep the main engine's connections. No overflow; a statement runs at most
    ``reader_statement_timeout_s``. PostgreSQL also ends a transaction left idle
    (``idle_in_transaction_session_timeout``). SQLite connections are query-only; readers there fetch in
    short chunks, each on a connection taken and given back, so no read transaction outlives a chunk and
    checkpoints keep the WAL bounded while a client is slow."""
    url = make_url(settings.database_url)
    size = settings.reader_pool_size
    timeout_ms = int(settings.reader_statement_timeout_s * 1000)
    if url.get_backend_name() == "sqlite":
        engine = create_engine(url, connect_args={"check_same_thread": False}, pool_size=size, max_overflow=0)
        pragmas = _sqlite_pragmas(settings.sqlite_synchronous)

        def query_only(dbapi_conn: Any, record: Any) -> None:
            pragmas(dbapi_conn, record)
            dbapi_conn.execute("PRAGMA query_only=1")

        event.listen(engine, "connect", query_only)
        if timeout_ms:
            _sqlite_statement_timeout(engine, settings.reader_statement_timeout_s)
        return engine
    options = f"-c statement_timeout={timeout_ms} -c idle_in_transaction_session_timeout="
    options += str(int(settings.reader_idle_timeout_s * 1000))
    return create_engine(url, pool_size=size, max_overflow=0, pool_pre_ping=True, connect_args={"options": options})


def is_read_timeout(exc: BaseException) -> bool:
    """A reader's statement cancelled for running too long (PostgreSQL 57014, SQLite "interrupted")."""
    orig = getattr(exc, "orig", exc)
    return getattr(orig, "sqlstate", None) == "57014" or "interrupted" in str(orig)


def alembic_config() -> Config:
    return Config(str(ALEMBIC_INI))


def upgrade_to_head(engine: Engine) -> None:
    """Upgrade to every head ("heads": a branch being merged never stops the server from starting)."""
    cfg = alembic_config()
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "heads")
    log.info("database schema at %s", current_revision(engine))


def upgrade_to(engine: Engine, revision: str) -> None:
    cfg = alembic_config()
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, revision)


def downgrade_to(engine: Engine, revision: str) -> None:
    """Back to ``revision`` (e.g. before reinstalling an older release; "base" empties the schema)."""
    cfg = alembic_config()
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.downgrade(cfg, revision)


def current_revision(engine: Engine) -> str | None:
    """The schema revision ("a,b" while two branches are applied), None for an empty database."""
    with engine.connect() as conn:
        heads = MigrationContext.configure(conn).get_current_heads()
    return ",".join(sorted(heads)) if heads else None
