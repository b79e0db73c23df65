"""SQLite runs in WAL mode with synchronous=NORMAL and a busy timeout: readers never block the writer
thread, and a second writer (the rollup job) waits instead of failing."""

from __future__ import annotations

import contextlib
import threading
import time

import pytest
from sqlalchemy import event, make_url, text
from sqlalchemy.exc import OperationalError

from backend.core.config import Settings
from backend.store.db import create_db_engine


def test_sqlite_pragmas(engine, database_url):
    if make_url(database_url).get_backend_name() != "sqlite":
        pytest.skip("SQLite only")
    with engine.connect() as conn:
        assert conn.execute(text("PRAGMA journal_mode")).scalar_one() == "wal"
        assert conn.execute(text("PRAGMA synchronous")).scalar_one() == 1  # NORMAL
        assert conn.execute(text("PRAGMA busy_timeout")).scalar_one() == 5000


def _hammer(engine, gated: bool, name: str, errors: list[str], rounds: int = 60) -> None:
    """Back-to-back write transactions that hold the database for a moment each, as rollup chunks do."""
    from backend.store.db import write_turn

    for i in range(rounds):
        try:
            with write_turn(engine, yield_after=True) if gated else contextlib.nullcontext(), engine.begin() as conn:
                conn.execute(text("INSERT INTO gate_probe (who, n) VALUES (:w, :n)"), {"w": name, "n": i})
                time.sleep(0.002)  # the write lock is held until the commit
        except OperationalError as exc:
            errors.append(str(exc.orig))


def _contend(tmp_path, gated: bool) -> tuple[list[str], int]:
    """Two threads of writers on an engine whose busy timeout is 0: any wait for the lock inside SQLite is
    an immediate "database is locked" error."""
    engine = create_db_engine(Settings(database_url=f"sqlite:///{tmp_path / f'gate-{gated}.db'}"))
    event.listen(engine, "connect", lambda conn, _rec: conn.execute("PRAGMA busy_timeout=0"))
    try:
        with engine.begin() as conn:
            conn.execute(text("CREATE TABLE gate_probe (who TEXT, n INTEGER)"))
        errors: list[str] = []
        threads = [threading.Thread(target=_hammer, args=(engine, gated, f"w{k}", errors)) for k in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        with engine.connect() as conn:
            stored = conn.execute(text("SELECT count(*) FROM gate_probe")).scalar_one()
        return errors, stored
    finally:
        engine.dispose()


def test_in_process_writers_take_turns_instead_of_meeting_a_locked_database(tmp_path):
    """The telemetry writer and the rollup job queue on write_turn's lock: neither ever waits in SQLite's
    busy handler (which sleeps up to 100 ms per poll). Without the gate the same load collides."""
    errors, stored = _contend(tmp_path, gated=True)
    assert errors == [] and stored == 120
    errors, stored = _contend(tmp_path, gated=False)
    assert errors and all("database is locked" in e for e in errors), errors[:3]
