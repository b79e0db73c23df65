"""The single writer thread: batches telemetry inserts by size and time, runs other writes in order.

The event loop only ever calls the non-blocking ``submit_*`` methods. Telemetry is inserted with
``ON CONFLICT DO NOTHING`` on (robot_id, stream, seq, ts) so QoS 1 redeliveries are stored once.
Other writes (robots, commands, acks, events) go through the same FIFO queue so their order is kept.

Broker acknowledgements: after the dispatcher has handled a burst of MQTT messages the bridge queues
an ack marker (:meth:`BatchWriter.submit_ack`) behind every write those messages caused. The marker's
tokens are handed to ``on_acks`` only once everything queued before it is committed, so a QoS 1 message
is PUBACKed to the broker only after its row is in the database: a crash before the commit means the
broker delivers it again (stored once thanks to the unique key). While acks wait, a batch is committed
after ``ack_linger_s`` (not the full interval) once nothing else is queued, so the broker's in-flight
window keeps moving under light load without a commit per message under heavy load.

Failures: a batch that fails for an operational reason (connection lost, database locked) is kept and
retried with backoff, its acks held back; rows the database refuses (data errors) are retried one by one
and the bad ones dropped and counted, so one poison row never blocks ingest.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, Engine
from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError

from backend.core.logging import RateLimitedLogger
from backend.store.db import write_turn
from backend.store.telemetry_inserts import (
    SQLITE_TELEMETRY_INSERT,
    TELEMETRY_COLUMNS,
    copy_telemetry_pg,
    dirty_marks,
    minutes_of,
    telemetry_insert,
)
from fleet_common.backoff import Backoff

log = logging.getLogger(__name__)

Op = Callable[[Connection], Any]
AckCallback = Callable[[list[Any]], None]
_STOP = object()
MAX_BACKOFF_S = 5.0
#: while items keep coming (one came within BUSY_WINDOW_S), the writer wakes at most once per tick
WAKE_TICK_S = 0.005
BUSY_WINDOW_S = 0.1
#: a telemetry batch commit slower than this is counted and logged (rate-limited)
SLOW_BATCH_S = 0.2


class _OpItem:
    __slots__ = ("after_rows", "fn", "future")

    def __init__(self, fn: Op, future: concurrent.futures.Future[Any] | None, after_rows: bool = True) -> None:
        self.fn = fn
        self.future = future
        self.after_rows = after_rows


class _AckItem:
    __slots__ = ("tokens",)

    def __init__(self, tokens: list[Any]) -> None:
        self.tokens = tokens


def is_transient(exc: BaseException) -> bool:
    """Worth retrying the same rows later (the database is away or busy), as opposed to bad data."""
    if isinstance(exc, OperationalError | InterfaceError):
        return True
    if not isinstance(exc, DBAPIError) and type(exc).__name__ in ("OperationalError", "InterfaceError"):
        return True  # the driver's own (PEP 249) class: raised by the COPY path, which bypasses SQLAlchemy
    return isinstance(exc, DBAPIError) and bool(exc.connection_invalidated)


class BatchWriter:
    def __init__(
        self,
        engine: Engine,
        batch_rows: int = 1000,
        interval_s: float = 0.1,
        queue_max: int = 100_000,
        on_acks: AckCallback | None = None,
        ack_linger_s: float = 0.02,
    ) -> None:
        self._engine = engine
        self._batch_rows = batch_rows
        self._interval = interval_s
        self._ack_linger = min(ack_linger_s, interval_s)
        self._queue_max = queue_max
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=queue_max)
        self._thread = threading.Thread(target=self._run, name="db-writer", daemon=True)
        self._insert = telemetry_insert(engine)
        self._dialect = engine.dialect.name
        self._dirty = dirty_marks(engine)
        self._rl = RateLimitedLogger(log)
        #: called on the writer thread with the tokens of committed ack markers (the bridge PUBACKs them)
        self.on_acks = on_acks
        self.rows_submitted = 0
        self.rows_written = 0  # rows actually inserted (duplicates excluded when the driver reports it)
        self.rows_dropped = 0  # queue full, or retry buffer overflow: never acked to the broker
        self.rows_rejected = 0  # refused by the database (bad data): dropped, acked
        self.batches = 0
        self.errors = 0
        self.retries = 0
        self.acks = 0
        self.acks_withheld = 0
        #: the longest telemetry batch write (ms), and how many took over SLOW_BATCH_S: the broker stops
        #: sending while the PUBACKs of an in-flight window's worth of messages wait for a commit
        self.slowest_batch_ms = 0.0
        self.slow_batches = 0
        self._drops_at_last_ack = 0
        # writer-thread state
        self._rows: list[dict[str, Any]] = []
        self._pending_acks: list[Any] = []
        self._failing = False
        self._retry_at = 0.0
        self._backoff = Backoff(0.2, MAX_BACKOFF_S)
        self._last_item = 0.0

    # -- loop side (non-blocking) -------------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def submit_telemetry(self, row: dict[str, Any]) -> bool:
        return self.submit_rows([row])

    def submit_rows(self, rows: list[dict[str, Any]]) -> bool:
        """Queue telemetry rows as one item (a drain's worth: one queue operation, not one per row)."""
        if not rows:
            return True
        try:
            self._queue.put_nowait(rows)
        except queue.Full:
            self.rows_dropped += len(rows)
            self._rl.warning("full", "telemetry write queue full: rows dropped (%d so far)", self.rows_dropped)
            return False
        self.rows_submitted += len(rows)
        return True

    def submit(
        self, fn: Op, want_result: bool = False, after_rows: bool = True
    ) -> concurrent.futures.Future[Any] | None:
        """Queue a write. With ``want_result`` a future resolves once it is committed. Writes stay in order;
        ``after_rows=False`` lets one that does not depend on telemetry (a new command's row) commit
        without first committing the telemetry rows queued before it (up to a batch of them)."""
        fut: concurrent.futures.Future[Any] | None = concurrent.futures.Future() if want_result else None
        try:
            self._queue.put_nowait(_OpItem(fn, fut, after_rows))
        except queue.Full:
            self.errors += 1
            log.error("write queue full: database write dropped")
            if fut is not None:
                fut.set_exception(RuntimeError("database write queue full"))
        return fut

    def read_then(self, fn: Op, on_result: Callable[[Any], None]) -> None:
        """Run ``fn`` on the writer thread (in order with the writes, without waiting for telemetry rows) and
        hand its result to ``on_result`` on the calling event loop; a failed read is left for the next one.
        Services that re-read shared rows once a second (replicas' leases, alarms) use it instead of blocking
        the loop on the database."""
        fut = self.submit(fn, want_result=True, after_rows=False)
        if fut is None:
            return
        loop = asyncio.get_running_loop()

        def done(f: concurrent.futures.Future[Any]) -> None:
            if not f.cancelled() and f.exception() is None:
                loop.call_soon_threadsafe(on_result, f.result())

        fut.add_done_callback(done)

    def submit_ack(self, tokens: list[Any]) -> bool:
        """Hand ``tokens`` to ``on_acks`` once every write queued so far is committed.

        If a row was dropped since the previous marker, the tokens are withheld (never acked): the broker
        keeps those messages and delivers them again after the next reconnect."""
        if not tokens:
            return True
        if self.rows_dropped != self._drops_at_last_ack:
            self._drops_at_last_ack = self.rows_dropped
            self.acks_withheld += len(tokens)
            self._rl.warning("withheld", "rows were dropped: %d broker acks withheld", self.acks_withheld)
            return False
        try:
            self._queue.put_nowait(_AckItem(tokens))
        except queue.Full:
            self.acks_withheld += len(tokens)
            return False
        return True

    def stats(self) -> dict[str, int | float]:
        return {
            "queued": self._queue.qsize(),
            "slowest_batch_ms": round(self.slowest_batch_ms, 1),
            "slow_batches": self.slow_batches,
            "rows_submitted": self.rows_submitted,
            "rows_written": self.rows_written,
            "rows_dropped": self.rows_dropped,
            "rows_rejected": self.rows_rejected,
            "batches": self.batches,
            "errors": self.errors,
            "retries": self.retries,
            "acks": self.acks,
            "acks_withheld": self.acks_withheld,
        }

    def stop(self, timeout: float = 10.0) -> None:
        if not self._thread.is_alive():
            return
        self._queue.put(_STOP)  # blocking is fine at shutdown; the thread drains the queue
        self._thread.join(timeout)

    # -- writer thread --------------------------------------------------------------------------------
    def _run(self) -> None:
        first = 0.0  # when the oldest row of the batch arrived
        while True:
            timeout: float | None = None
            if self._rows:
                due = first + (self._ack_linger if self._pending_acks else self._interval)
                timeout = (self._retry_at if self._failing else due) - time.monotonic()
                if timeout <= 0:  # due (a steady stream of items never lets get() time out)
                    self._flush()
                    continue
            if self._queue.empty() and time.monotonic() - self._last_item < BUSY_WINDOW_S:
                # Busy: let items gather for a tick instead of waking for each one. Each wake took the GIL
                # from the event loop (a wake per MQTT drain at 2,000 msg/s), delaying commands and acks.
                time.sleep(WAKE_TICK_S if timeout is None else max(0.0, min(WAKE_TICK_S, timeout)))
            try:
                item = self._queue.get(timeout=timeout)
            except queue.Empty:
                self._flush()
                continue
            self._last_item = time.monotonic()
            if item is _STOP:
                self._final_flush()
                return
            if isinstance(item, _OpItem):
                if not self._failing and item.after_rows:
                    self._flush()  # keep the order: rows queued before the op are committed before it
                self._run_op(item)
                self._ack_if_clear()
                continue
            if isinstance(item, _AckItem):
                self._pending_acks.extend(item.tokens)
                if not self._rows:
                    self._ack_if_clear()
                elif not self._failing and self._queue.empty() and time.monotonic() - first >= self._ack_linger:
                    self._flush()  # group commit: the broker waits for this ack, nothing else is queued
                continue
            if not self._rows:
                first = time.monotonic()
            if isinstance(item, list):
                self._rows.extend(item)
            else:
                self._rows.append(item)
            if len(self._rows) >= self._batch_rows and not self._failing:
                self._flush()

    def _ack_if_clear(self) -> None:
        if self._rows or not self._pending_acks:
            return
        tokens, self._pending_acks = self._pending_acks, []
        if self.on_acks is None:
            return
        try:
            self.on_acks(tokens)
            self.acks += len(tokens)
        except Exception:
            self.errors += 1
            log.exception("sending %d broker acks failed", len(tokens))

    def _flush(self) -> None:
        if not self._rows:
            self._ack_if_clear()
            return
        if self._failing and time.monotonic() < self._retry_at:
            return
        if self._write_rows(self._rows):
            self._rows = []
            self._failing = False
            self._backoff.reset()
            self._ack_if_clear()
            return
        self._failing = True
        self.retries += 1
        self._retry_at = time.monotonic() + self._backoff.next()
        overflow = len(self._rows) - self._queue_max
        if overflow > 0:  # bounded: the oldest rows go (never acked, so the broker still has them)
            del self._rows[:overflow]
            self.rows_dropped += overflow

    def _final_flush(self) -> None:
        for _ in range(3):
            self._failing = False
            self._flush()
            if not self._rows:
                return
            time.sleep(0.2)
        log.error("shutting down with %d telemetry rows not stored (the broker still holds them)", len(self._rows))

    def _write_rows(self, rows: list[dict[str, Any]]) -> bool:
        """True when the rows are committed (minus rows the database refused); False: retry later."""
        started = time.monotonic()
        try:
            return self._commit_rows(rows)
        finally:
            took = time.monotonic() - started
            self.slowest_batch_ms = max(self.slowest_batch_ms, took * 1000)
            if took > SLOW_BATCH_S:
                self.slow_batches += 1
                self._rl.warning("slow", "a telemetry batch of %d rows took %.0f ms to commit", len(rows), took * 1000)

    def _commit_rows(self, rows: list[dict[str, Any]]) -> bool:
        try:
            with write_turn(self._engine), self._engine.begin() as conn:
                if self._dialect == "postgresql":
                    written = copy_telemetry_pg(conn, rows)
                else:
                    result = (
                        conn.exec_driver_sql(
                            SQLITE_TELEMETRY_INSERT, [tuple(r[c] for c in TELEMETRY_COLUMNS) for r in rows]
                        )
                        if self._dialect == "sqlite"
                        else conn.execute(self._insert, rows)
                    )
                    written = result.rowcount if result.rowcount is not None and result.rowcount >= 0 else len(rows)
                conn.execute(self._dirty, minutes_of(rows))
        except Exception as exc:
            self.errors += 1
            if is_transient(exc):
                self._rl.warning("transient", "telemetry batch of %d rows not stored, will retry: %s", len(rows), exc)
                return False
            log.warning("telemetry batch refused (%s); inserting its %d rows one by one", exc, len(rows))
            return self._write_one_by_one(rows)
        self.rows_written += written
        self.batches += 1
        return True

    def _write_one_by_one(self, rows: list[dict[str, Any]]) -> bool:
        for row in rows:
            try:
                with write_turn(self._engine), self._engine.begin() as conn:
                    conn.execute(self._insert, [row])
                    conn.execute(self._dirty, minutes_of([row]))
                self.rows_written += 1
            except Exception as exc:
                if is_transient(exc):
                    return False
                self.rows_rejected += 1
                self._rl.warning(
                    "rejected",
                    "telemetry row refused by the database (%s/%s seq %s): %s",
                    row.get("robot_id"),
                    row.get("stream"),
                    row.get("seq"),
                    exc,
                )
        self.batches += 1
        return True

    def _run_op(self, item: _OpItem) -> None:
        try:
            with write_turn(self._engine), self._engine.begin() as conn:
                result = item.fn(conn)
        except Exception as exc:
            self.errors += 1
            log.exception("database write failed")
            if item.future is not None:
                item.future.set_exception(exc)
            return
        if item.future is not None:
            item.future.set_result(result)
