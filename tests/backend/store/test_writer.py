"""The batch writer's promises to the broker: an ack marker is released only after everything queued before
it is committed; a database that is away holds the acks back and the rows are retried, not lost; rows the
database refuses are dropped one by one without blocking the rest; a dropped row withholds its acks."""

from __future__ import annotations

import sqlite3
import threading
from typing import Any

from sqlalchemy import create_engine, make_url, text

from backend.services.telemetry.ingest import telemetry_row
from backend.store.writer import BatchWriter
from tests.support.procs import wait_for


def _rows(robot: str, n: int, start: int = 0) -> list[dict[str, Any]]:
    return [telemetry_row(robot, "position", 1000.0 + i, i, {"x": float(i), "y": 0.0}) for i in range(start, start + n)]


def _count(engine, robot: str) -> int:  # type: ignore[no-untyped-def]
    with engine.connect() as conn:
        return int(conn.execute(text("SELECT count(*) FROM telemetry WHERE robot_id = :r"), {"r": robot}).scalar_one())


def test_acks_follow_the_commit(engine):
    seen: list[tuple[list[Any], int]] = []

    def on_acks(tokens: list[Any]) -> None:
        seen.append((tokens, _count(engine, "w1")))  # what a fresh connection sees when the ack goes out

    writer = BatchWriter(engine, batch_rows=10_000, interval_s=5.0, on_acks=on_acks)
    writer.start()
    try:
        for r in _rows("w1", 250):
            writer.submit_telemetry(r)
        assert writer.submit_ack([(1, 1), (1, 2)])
        # group commit: the marker commits the batch at once instead of waiting the 5 s interval
        wait_for(lambda: seen, 3, what="acks")
        assert seen == [([(1, 1), (1, 2)], 250)]
        # an ack with nothing pending goes out at once; ops keep their order with rows
        assert writer.submit_ack([(1, 3)])
        wait_for(lambda: len(seen) == 2, 3)
        assert seen[1] == ([(1, 3)], 250)
    finally:
        writer.stop()
    assert writer.stats()["acks"] == 3 and writer.stats()["rows_written"] == 250
    with engine.connect() as conn:  # the minutes the rows touched are marked for the rollup
        marks = conn.execute(text("SELECT minute_ts FROM telemetry_dirty WHERE robot_id = 'w1' ORDER BY 1"))
        assert [m for (m,) in marks] == sorted({(1000.0 + i) // 60 * 60 for i in range(250)})


def test_database_away_holds_acks_then_retries(database_url):
    """The telemetry table is locked by another session: the batch fails, is retried, and only then acked."""
    from backend.core.config import Settings
    from backend.store.db import create_db_engine, upgrade_to_head

    setup = create_db_engine(Settings(database_url=database_url))
    upgrade_to_head(setup)
    setup.dispose()
    url = make_url(database_url)
    blocker: Any
    if url.get_backend_name() == "sqlite":
        engine = create_engine(database_url, connect_args={"timeout": 0.05})  # busy: fail fast, then retry
        blocker = sqlite3.connect(str(url.database), isolation_level=None)
        blocker.execute("BEGIN EXCLUSIVE")
    else:
        import psycopg

        engine = create_engine(database_url, connect_args={"options": "-c lock_timeout=50"})
        blocker = psycopg.connect(url.set(drivername="postgresql").render_as_string(hide_password=False))
        blocker.execute("LOCK TABLE telemetry IN ACCESS EXCLUSIVE MODE")
    acks: list[Any] = []
    writer = BatchWriter(engine, batch_rows=100, interval_s=0.01, on_acks=acks.extend)
    writer.start()
    try:
        for r in _rows("w2", 300):
            writer.submit_telemetry(r)
        writer.submit_ack([(1, 7)])
        wait_for(lambda: writer.retries >= 2, 10, what="retries while locked")
        assert acks == [] and writer.rows_dropped == 0
        blocker.rollback() if url.get_backend_name() != "sqlite" else blocker.execute("ROLLBACK")
        wait_for(lambda: acks == [(1, 7)], 15, what="ack after the lock is gone")
        assert _count(engine, "w2") == 300
    finally:
        blocker.close()
        writer.stop()
        engine.dispose()


def test_refused_rows_are_dropped_alone(engine):
    acks: list[Any] = []
    writer = BatchWriter(engine, batch_rows=1000, interval_s=0.05, on_acks=acks.extend)
    writer.start()
    try:
        rows = _rows("w3", 50)
        rows[20] = dict(rows[20], payload=None)  # NOT NULL: the database refuses this one row
        for r in rows:
            writer.submit_telemetry(r)
        writer.submit_ack([(1, 1)])
        wait_for(lambda: acks, 10, what="ack")
    finally:
        writer.stop()
    assert _count(engine, "w3") == 49 and writer.rows_rejected == 1 and writer.rows_dropped == 0


def test_a_dropped_row_withholds_its_ack(engine):
    acks: list[Any] = []
    gate = threading.Event()
    busy = threading.Event()

    def slow_op(conn: Any) -> None:
        busy.set()
        gate.wait(10)

    writer = BatchWriter(engine, batch_rows=1000, interval_s=0.05, queue_max=100, on_acks=acks.extend)
    writer.start()
    try:
        writer.submit(slow_op)
        assert busy.wait(10)  # the writer is busy in it: the queue fills up
        accepted = [writer.submit_telemetry(r) for r in _rows("w4", 150)]
        assert accepted.count(False) == writer.rows_dropped > 0
        assert writer.submit_ack([(1, 1)]) is False  # never acked: the broker keeps the message
        gate.set()
        wait_for(lambda: writer.stats()["queued"] == 0, 10, what="queue drained")
        assert writer.submit_ack([(1, 2)]) is True  # later messages are acked again
        wait_for(lambda: acks == [(1, 2)], 10, what="next ack")
    finally:
        gate.set()
        writer.stop()
    assert writer.acks_withheld == 1
