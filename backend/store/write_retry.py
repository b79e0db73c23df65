"""The writer's retry queue: database writes (audit rows, commands, events, e-stop records) that failed for an
operational reason wait here, in their order, and are retried until they are stored.

Bounded (``FLEET_WRITER_RETRY_MAX``): a write that finds the queue full is given up explicitly. Its future
fails with :class:`StoreUnavailable` (a caller waiting for it hears why), it is counted (``ops_dropped``,
``fleet_store_ops_dropped_total``) and logged, the broker ack of the message that caused it is withheld
(see writer.py) and the alarms raise ``store_writes_lost``. Holding more would only move the failure to the
process's memory; blocking the event loop instead would stop the e-stop with it.
"""

from __future__ import annotations

import concurrent.futures
import logging
from collections import deque
from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, Engine
from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError

from backend.core.errors import ServiceError
from backend.core.logging import RateLimitedLogger
from backend.store.db import write_turn

log = logging.getLogger(__name__)

Op = Callable[[Connection], Any]


class StoreUnavailable(ServiceError):
    """The database could not take this write or read now, and it was given up: an API request that waited
    for it answers 503 ``database_unavailable``."""

    def __init__(self, detail: str) -> None:
        super().__init__(503, detail, "database_unavailable")


class OpItem:
    """One queued database operation. ``retry``: a write kept until stored (False: a read, which the next
    periodic read replaces, so it fails at once while the database is unavailable)."""

    __slots__ = ("after_rows", "fn", "future", "retry")

    def __init__(
        self, fn: Op, future: concurrent.futures.Future[Any] | None, after_rows: bool = True, retry: bool = True
    ) -> None:
        self.fn = fn
        self.future = future
        self.after_rows = after_rows
        self.retry = retry

    def fail(self, exc: BaseException) -> None:
        if self.future is not None and not self.future.done():
            self.future.set_exception(exc)


_PEP249_TRANSIENT = ("OperationalError", "InterfaceError")


def is_transient(exc: BaseException) -> bool:
    """Worth retrying the same rows later (the database is away or busy), as opposed to bad data."""
    if isinstance(exc, OperationalError | InterfaceError):
        return True
    if not isinstance(exc, DBAPIError) and any(c.__name__ in _PEP249_TRANSIENT for c in type(exc).__mro__):
        return True  # the driver's own (PEP 249) classes, e.g. LockNotAvailable: the COPY path bypasses SQLAlchemy
    return isinstance(exc, DBAPIError) and bool(exc.connection_invalidated)


class RetryQueue:
    """Runs the writer's operations, and keeps the writes waiting for the database, oldest first (writer
    thread only)."""

    def __init__(self, engine: Engine, limit: int) -> None:
        self._engine = engine
        self.limit = limit
        self._items: deque[OpItem] = deque()
        self._rl = RateLimitedLogger(log)
        #: writes given up because the queue was full
        self.dropped = 0
        #: writes the database refused (bad data, a bug): their callers got the error
        self.refused = 0
        self.errors = 0

    def attempt(self, item: OpItem) -> bool:
        """Run one operation in its own transaction. False: the database is unavailable, retry it later."""
        try:
            with write_turn(self._engine), self._engine.begin() as conn:
                result = item.fn(conn)
        except Exception as exc:
            self.errors += 1
            if is_transient(exc) and item.retry:
                self._rl.warning("transient", "database write not stored, will retry: %s", exc)
                return False
            if not is_transient(exc):
                self.refused += 1
                log.exception("database write refused")
                item.fail(exc)
            else:  # an operation asked now or never (retry=False): its caller hears 503, not the driver's error
                item.fail(StoreUnavailable(f"database unavailable: {type(exc).__name__}"))
            return True
        if item.future is not None:
            item.future.set_result(result)
        return True

    def __len__(self) -> int:
        return len(self._items)

    @property
    def full(self) -> bool:
        return len(self._items) >= self.limit

    def hold(self, item: OpItem) -> bool:
        """Keep ``item`` for a retry; False when the queue is full and the write was given up."""
        if self.full:
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 100 == 0:
                log.error(
                    "database unavailable and %d writes already waiting: a write was given up (%d so far)",
                    self.limit,
                    self.dropped,
                )
            item.fail(StoreUnavailable(f"database unavailable and {self.limit} writes already waiting"))
            return False
        self._items.append(item)
        return True

    def run(self) -> bool:
        """Retry in order until one fails again: True when all are done."""
        while self._items:
            if not self.attempt(self._items[0]):
                return False
            self._items.popleft()
        return True

    def give_up(self, why: str) -> int:
        """At shutdown: fail what is left (its callers hear ``why``); returns how many."""
        left = len(self._items)
        while self._items:
            self._items.popleft().fail(StoreUnavailable(why))
        return left
