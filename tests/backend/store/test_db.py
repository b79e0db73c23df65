"""SQLite runs in WAL mode with synchronous=NORMAL and a busy timeout: readers never block the writer
thread, and a second writer (the rollup job) waits instead of failing."""

from __future__ import annotations

import pytest
from sqlalchemy import make_url, text


def test_sqlite_pragmas(engine, database_url):
    if make_url(database_url).get_backend_name() != "sqlite":
        pytest.skip("SQLite only")
    with engine.connect() as conn:
        assert conn.execute(text("PRAGMA journal_mode")).scalar_one() == "wal"
        assert conn.execute(text("PRAGMA synchronous")).scalar_one() == 1  # NORMAL
        assert conn.execute(text("PRAGMA busy_timeout")).scalar_one() == 5000
