"""Store tests run against a real database (SQLite file, or PostgreSQL with --database postgres)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from sqlalchemy import Engine

from backend.core.config import Settings
from backend.store.db import create_db_engine, upgrade_to_head


@pytest.fixture
def engine(database_url: str) -> Iterator[Engine]:
    eng = create_db_engine(Settings(database_url=database_url))
    upgrade_to_head(eng)
    try:
        yield eng
    finally:
        eng.dispose()
