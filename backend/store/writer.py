"""The single writer thread: batches telemetry inserts by size and time, runs other writes in order.

The event loop only ever calls the non-blocking ``submit_*`` methods. Telemetry is inserted with ``ON CONFLICT
DO NOTHING`` on (robot_id, stream, seq, ts) so QoS 1 redeliveries are stored once. Other writes (robots,
commands, acks, events) go through the same FIFO queue so their order is kept.

Broker acknowledgements: after the dispatcher has handled a burst of MQTT messages the bridge queues
an ack marker (:meth:`BatchWriter.submit_ack`) behind every write those messages caused. The marker's
tokens go to ``on_acks`` only once everything queued before it is committed: a QoS 1 message is PUBACKed
only after its row is in the database, and a crash before the commit means the broker delivers it again.
While acks wait, a batch is committed after ``ack_linger_s`` once nothing else is queued, so the broker's
in-flight window keeps moving under light load without a commit per message under heavy load.

Nothing acked that was not stored. A database that is away (connection lost, locked) keeps the failed
batch and every write behind it, retried with backoff, their acks held back; other writes (audit, commands,
events, e-stop records) wait in a bounded retry queue (write_retry.py). What cannot be kept is given up
explicitly and the acks of its messages are *withheld* (``on_withheld``), never sent: rows refused at the
full queue or trimmed from the retry buffer (over ``queue_max`` rows, the oldest go), writes refused at a
full queue or retry queue. All counted (/api/stats, /metrics); alarms: ``telemetry_not_stored``, ``store_writes_lost``.

A withheld ack holds a slot of the broker's in-flight window for as long as the connection lasts (a broker
sends an unacknowledged message again only on a new connection of the session). So the bridge reconnects
on purpose once acks were withheld and the writer has :meth:`caught_up`: the broker delivers the withheld
messages again, they are stored once and acked, and the window is whole (earlier, they would only be dropped
again). Rows the database refuses (bad data) are dropped one by one, counted (``rows_rejected``) and acked:
a redelivery would be refused alike, and one poison row must never block ingest.
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

from sqlalchemy import Engine

from backend.core.logging import RateLimitedLogger
from backend.store.telemetry_inserts import TelemetryCommitter
from backend.store.write_retry import Op, OpItem, RetryQueue, StoreUnavailable, is_transient
from fleet_common.backoff import Backoff

__all__ = ["BatchWriter", "StoreUnavailable", "is_transient"]

log = logging.getLogger(__name__)

AckCallback = Callable[[list[Any]], None]
_STOP = object()
MAX_BACKOFF_S = 5.0
#: while items keep coming (one came within BUSY_WINDOW_S), the writer wakes at most once per tick
WAKE_TICK_S = 0.005
BUSY_WINDOW_S = 0.1


class _AckItem:
    __slots__ = ("tokens",)

    def __init__(self, tokens: list[Any]) -> None:
        self.tokens = tokens


class BatchWriter:
    def __init__(
        self,
        engine: Engine,
        batch_rows: int = 1000,
        interval_s: float = 0.1,
        queue_max: int = 100_000,
        on_acks: AckCallback | None = None,
        ack_linger_s: float = 0.02,
        retry_max: int = 10_000,
        on_withheld: AckCallback | None = None,
    ) -> None:
        self._engine = engine
        self._batch_rows = batch_rows
        self._interval = interval_s
        self._ack_linger = min(ack_linger_s, interval_s)
        self._queue_max = queue_max
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=queue_max)
        self._thread = threading.Thread(target=self._run, name="db-writer", daemon=True)
        self._committer = TelemetryCommitter(engine)
        self._rl = RateLimitedLogger(log)
        #: called on the writer thread with the tokens of committed ack markers (the bridge PUBACKs them)
        self.on_acks = on_acks
        #: called (writer thread or event loop) with tokens never to be acked: their messages were not stored
        self.on_withheld = on_withheld
        self.rows_submitted = 0
        self._callback_errors = 0
        self.retries = 0
        self.acks = 0
        # counted on the event loop (submit_*) and on the writer thread apart: no lost increments
        self._loop_rows_dropped = self._loop_ops_dropped = self._loop_acks_withheld = 0
        self._rows_trimmed = self._thread_acks_withheld = 0
        #: event loop: something since the last ack marker was not queued, so that marker is withheld
        self._unqueued_since_marker = False
        # writer-thread state
        self._rows: list[dict[str, Any]] = []
        self._pending_acks: list[Any] = []
        self._retry = RetryQueue(engine, retry_max)
        #: the next ack marker covers something given up: withhold it
        self._withhold_next = False
        self._failing = False
        self._retry_at = 0.0
        self._backoff = Backoff(0.2, MAX_BACKOFF_S)
        self._last_item = 0.0

    # -- counters (both threads) -------------------------------------------------------------------
    @property
    def rows_dropped(self) -> int:
        """Telemetry rows not stored: the queue was full, or trimmed from the retry buffer (never acked)."""
        return self._loop_rows_dropped + self._rows_trimmed

    @property
    def ops_dropped(self) -> int:
        """Other writes given up: the queue or the retry queue was full (never acked)."""
        return self._loop_ops_dropped + self._retry.dropped

    @property
    def acks_withheld(self) -> int:
        return self._loop_acks_withheld + self._thread_acks_withheld

    @property
    def errors(self) -> int:
        """Failed telemetry batches, failed writes and failed ack callbacks."""
        return self._callback_errors + self._committer.errors + self._retry.errors

    @property
    def rows_rejected(self) -> int:
        """Telemetry rows the database refused (bad data): dropped and acked (a redelivery would fail alike)."""
        return self._committer.rows_rejected

    def caught_up(self) -> bool:
        """The database takes writes again and the backlog is short: withheld messages can come back now."""
        half = self._queue_max // 2
        return not self._failing and not self._retry and self._queue.qsize() < half and len(self._rows) < half

    def has_room(self) -> bool:
        """A write submitted now will be kept until it is stored (the queue and retry queue have room)."""
        return not self._retry.full and self._queue.qsize() < self._queue_max

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
            self._loop_rows_dropped += len(rows)
            self._unqueued_since_marker = True
            self._rl.warning("full", "telemetry write queue full: rows dropped (%d so far)", self.rows_dropped)
            return False
        self.rows_submitted += len(rows)
        return True

    def submit(
        self, fn: Op, want_result: bool = False, after_rows: bool = True, retry: bool = True
    ) -> concurrent.futures.Future[Any] | None:
        """Queue a write. With ``want_result`` a future resolves once it is committed: a write is retried
        until the database takes it (its caller waits that long), or fails with :class:`StoreUnavailable` if
        it had to be given up. Writes stay in order; ``after_rows=False`` lets one that does not depend on
        telemetry (a new command's row) commit without first committing the telemetry rows queued before it
        (up to a batch of them). ``retry=False``: done now or refused (503), e.g. reads and leases."""
        fut: concurrent.futures.Future[Any] | None = concurrent.futures.Future() if want_result else None
        try:
            self._queue.put_nowait(OpItem(fn, fut, after_rows, retry))
        except queue.Full:
            if retry:  # a write given up (a read is only refused: the next one replaces it)
                self._loop_ops_dropped += 1
                self._unqueued_since_marker = True
                log.error("write queue full: database write given up (%d so far)", self.ops_dropped)
            if fut is not None:
                fut.set_exception(StoreUnavailable("database write queue full"))
        return fut

    def read_then(self, fn: Op, on_result: Callable[[Any], None]) -> None:
        """Run ``fn`` on the writer thread (in order with the writes, without waiting for telemetry rows) and
        hand its result to ``on_result`` on the calling event loop; a failed read is left for the next one.
        Services that re-read shared rows once a second (replicas' leases, alarms) use it instead of blocking
        the loop on the database."""
        fut = self.submit(fn, want_result=True, after_rows=False, retry=False)
        if fut is None:
            return
        loop = asyncio.get_running_loop()

        def done(f: concurrent.futures.Future[Any]) -> None:
            if not f.cancelled() and f.exception() is None:
                loop.call_soon_threadsafe(on_result, f.result())

        fut.add_done_callback(done)

    def submit_ack(self, tokens: list[Any]) -> bool:
        """Hand ``tokens`` to ``on_acks`` once every write queued so far is committed.

        If a row or write could not be queued since the previous marker, the tokens are withheld (never
        acked): the broker keeps those messages and delivers them again (see the module docstring)."""
        if not tokens:
            return True
        if self._unqueued_since_marker:
            self._unqueued_since_marker = False
        else:
            try:
                self._queue.put_nowait(_AckItem(tokens))
                return True
            except queue.Full:
                pass
        self._loop_acks_withheld += len(tokens)
        self._rl.warning("withheld", "writes were given up: %d broker acks withheld", self.acks_withheld)
        self._tell_withheld(tokens)
        return False

    def stats(self) -> dict[str, int | float]:
        rows = self._committer
        return {
            "queued": self._queue.qsize(),
            "slowest_batch_ms": round(rows.slowest_batch_ms, 1),
            "slow_batches": rows.slow_batches,
            "rows_submitted": self.rows_submitted,
            "rows_written": rows.rows_written,
            "rows_dropped": self.rows_dropped,
            "rows_rejected": rows.rows_rejected,
            "batches": rows.batches,
            "errors": self.errors,
            "retries": self.retries,
            "failing": int(self._failing),
            "ops_retrying": len(self._retry),
            "ops_dropped": self.ops_dropped,
            "ops_refused": self._retry.refused,
            "acks": self.acks,
            "acks_withheld": self.acks_withheld,
        }

    def stop(self, timeout: float = 10.0) -> None:
        if not self._thread.is_alive():
            return
        self._queue.put(_STOP)  # blocking is fine at shutdown; the thread drains the queue
        self._thread.join(timeout)

    def _tell_withheld(self, tokens: list[Any]) -> None:
        if self.on_withheld is None:
            return
        try:
            self.on_withheld(tokens)
        except Exception:
            self._callback_errors += 1
            log.exception("reporting %d withheld broker acks failed", len(tokens))

    # -- writer thread --------------------------------------------------------------------------------
    def _run(self) -> None:
        first = 0.0  # when the oldest row of the batch arrived
        while True:
            timeout: float | None = None
            if self._failing:
                timeout = self._retry_at - time.monotonic()
                if timeout <= 0:
                    self._retry_now()
                    continue
            elif self._rows:
                timeout = first + (self._ack_linger if self._pending_acks else self._interval) - time.monotonic()
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
                continue  # due now: the top of the loop flushes or retries
            self._last_item = time.monotonic()
            if item is _STOP:
                self._final_flush()
                return
            if isinstance(item, OpItem):
                self._take_op(item)
                continue
            if isinstance(item, _AckItem):
                if self._withhold_next:  # it covers rows or writes given up
                    self._withhold_next = False
                    self._withhold(item.tokens)
                    continue
                self._pending_acks.extend(item.tokens)
                if not self._rows:
                    self._ack_if_clear()
                elif not self._failing and self._queue.empty() and time.monotonic() - first >= self._ack_linger:
                    self._flush()  # group commit: the broker waits for this ack, nothing else is queued
                continue
            if not self._rows:
                first = time.monotonic()
            self._rows.extend(item)
            if self._failing:
                self._trim()
            elif len(self._rows) >= self._batch_rows:
                self._flush()

    def _take_op(self, item: OpItem) -> None:
        if self._failing or self._retry:  # writes are waiting for the database: keep the order
            if item.retry:
                self._hold(item)
            else:
                item.fail(StoreUnavailable("database unavailable"))
            return
        if item.after_rows:
            self._flush()  # keep the order: rows queued before the op are committed before it
            if self._failing:
                self._hold(item)
                return
        if not self._retry.attempt(item):
            self._hold(item)
            self._retry_later()
            return
        self._ack_if_clear()

    def _hold(self, item: OpItem) -> None:
        if not self._retry.hold(item):  # given up: the message that caused it is not acked
            self._withhold_next = True

    def _withhold(self, tokens: list[Any]) -> None:
        self._thread_acks_withheld += len(tokens)
        self._tell_withheld(tokens)

    def _ack_if_clear(self) -> None:
        if self._rows or self._retry or self._failing or not self._pending_acks:
            return
        tokens, self._pending_acks = self._pending_acks, []
        if self.on_acks is None:
            return
        try:
            self.on_acks(tokens)
            self.acks += len(tokens)
        except Exception:
            self._callback_errors += 1
            log.exception("sending %d broker acks failed", len(tokens))

    def _flush(self) -> None:
        if not self._rows:
            self._ack_if_clear()
            return
        if self._committer.commit(self._rows):
            self._rows = []
            self._ack_if_clear()
            return
        self._retry_later()

    def _retry_now(self) -> None:
        """The backoff is over: the rows first (ops after rows were queued behind them), then the writes."""
        if self._rows and not self._committer.commit(self._rows):
            self._retry_later()
            return
        self._rows = []
        if not self._retry.run():
            self._retry_later()
            return
        self._failing = False
        self._backoff.reset()
        self._ack_if_clear()

    def _retry_later(self) -> None:
        self._failing = True
        self.retries += 1
        self._retry_at = time.monotonic() + self._backoff.next()
        self._trim()

    def _trim(self) -> None:
        """Bounded: the oldest rows go beyond ``queue_max``. Never acked, so the broker still has them: the
        acks waiting now and the next marker (it may cover trimmed rows read since the last) are withheld."""
        overflow = len(self._rows) - self._queue_max
        if overflow <= 0:
            return
        del self._rows[:overflow]
        self._rows_trimmed += overflow
        self._withhold_next = True
        tokens, self._pending_acks = self._pending_acks, []
        if tokens:
            self._withhold(tokens)
        self._rl.warning("trimmed", "database away: %d telemetry rows trimmed, acks withheld", self._rows_trimmed)

    def _final_flush(self) -> None:
        for _ in range(3):
            self._failing = False
            self._retry_now()
            if not self._rows and not self._retry:
                return
            time.sleep(0.2)
        log.error(
            "shutting down with %d telemetry rows and %d writes not stored (the broker still holds their messages)",
            len(self._rows),
            self._retry.give_up("server shutting down with the database unavailable"),
        )
