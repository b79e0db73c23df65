"""The readers' engine and their chunked reads (backend/store/db.py, telemetry_raw.py, run_reads.py): a
reader paused between chunks (its client not reading) holds no connection and, on SQLite, no snapshot
that keeps the WAL from being checkpointed; a reader's statement stops at the timeout; readers cannot
write."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path

import orjson
import pytest
from sqlalchemy import Engine, make_url, text
from sqlalchemy.exc import DBAPIError

from backend.core.config import Settings
from backend.store import run_reads
from backend.store.db import create_reader_engine, is_read_timeout
from backend.store.telemetry_inserts import telemetry_insert
from backend.store.telemetry_raw import iter_raw

ROWS = 5000


def _fill(engine: Engine, robot_id: str, stream: str, rows: int, t0: float) -> None:
    values = [
        {
            "robot_id": robot_id,
            "stream": stream,
            "seq": i,
            "ts": t0 + (i // 2) * 0.01,  # two rows share each time stamp: the chunks must split ties right
            "x": float(i),
            "y": 0.0,
            "z": 0.0,
            "yaw": 0.0,
            "payload": orjson.dumps({"x": float(i), "y": 0.0}).decode(),
            "recv_ts": None,
        }
        for i in range(rows)
    ]
    with engine.begin() as conn:
        conn.execute(telemetry_insert(engine), values)


@pytest.fixture
def reader(database_url: str) -> Iterator[Engine]:
    eng = create_reader_engine(Settings(database_url=database_url, reader_pool_size=1))
    try:
        yield eng
    finally:
        eng.dispose()


def test_a_paused_reader_holds_no_connection_and_reads_every_row_once(engine: Engine, reader: Engine) -> None:
    t0 = time.time() - 600
    _fill(engine, "r1", "position", ROWS, t0)
    _fill(engine, "r2", "position", ROWS // 2, t0)

    raw = iter_raw(reader, "r1", "position", None, None, batch=700)
    first = next(raw)
    assert len(first) == 700 and reader.pool.checkedout() == 0  # paused: nothing held
    seqs = [seq for _, seq, _, _ in first] + [seq for chunk in raw for _, seq, _, _ in chunk]
    assert seqs == list(range(ROWS))
    limited = iter_raw(reader, "r1", "position", None, None, limit=1500, batch=700)
    assert [seq for chunk in limited for _, seq, _, _ in chunk] == list(range(1500))

    # a run export's telemetry: two robots merged in time order, also paused between chunks
    rows = run_reads.iter_telemetry(reader, ["r1", "r2"], t0, t0 + 3600, batch=600)
    head = next(rows)
    assert (head.robot_id, head.seq) == ("r1", 0) and reader.pool.checkedout() == 0
    merged = [head, *rows]
    assert len(merged) == ROWS + ROWS // 2
    assert [(r.ts, r.seq) for r in merged] == sorted((r.ts, r.seq) for r in merged)
    assert sorted(r.seq for r in merged if r.robot_id == "r2") == list(range(ROWS // 2))


def _wal_bytes(database_url: str) -> int:
    path = Path(str(make_url(database_url).database) + "-wal")
    return path.stat().st_size if path.exists() else 0


def test_sqlite_wal_stays_bounded_while_a_reader_is_paused(engine: Engine, reader: Engine, database_url: str) -> None:
    if engine.dialect.name != "sqlite":
        pytest.skip("SQLite's WAL")
    _fill(engine, "r1", "position", ROWS, time.time() - 600)
    raw = iter_raw(reader, "r1", "position", None, None, batch=500)
    paused = [next(raw), next(raw)]  # an export whose client stopped reading after two chunks
    with engine.begin() as conn:
        conn.execute(text("CREATE TABLE wal_probe (n INTEGER, pad BLOB)"))
    pad = os.urandom(3000)
    for i in range(3000):  # about 3000 x 2 pages (12 MB) through the WAL, one commit each
        with engine.begin() as conn:
            conn.execute(text("INSERT INTO wal_probe (n, pad) VALUES (:n, :p)"), {"n": i, "p": pad})
    # checkpoints (every 1000 pages, 4 MB) run to the end and the WAL starts over: it stays near 4 MB
    assert _wal_bytes(database_url) < 8 * 1024 * 1024, _wal_bytes(database_url)
    assert len(paused[1]) == 500 and sum(len(c) for c in raw) == ROWS - 1000  # the reader then goes on


def test_a_readers_statement_stops_at_the_timeout(database_url: str) -> None:
    eng = create_reader_engine(Settings(database_url=database_url, reader_statement_timeout_s=0.2))
    slow = (
        "WITH RECURSIVE c(x) AS (SELECT 1 UNION ALL SELECT x + 1 FROM c WHERE x < 2000000000) SELECT count(*) FROM c"
        if eng.dialect.name == "sqlite"
        else "SELECT pg_sleep(30)"
    )
    try:
        with eng.connect() as conn:
            with pytest.raises(DBAPIError) as caught:
                conn.execute(text(slow))
            assert is_read_timeout(caught.value)
            conn.rollback()
            assert conn.execute(text("SELECT 1")).scalar_one() == 1  # the next statement gets its own time
            if eng.dialect.name == "sqlite":
                assert conn.execute(text("PRAGMA query_only")).scalar_one() == 1  # readers never write
            else:
                assert conn.execute(text("SHOW idle_in_transaction_session_timeout")).scalar_one() == "1min"
    finally:
        eng.dispose()
