"""Readers: history reads and exports, kept apart from the control plane.

A reader never takes what the writer, leases, audit, the e-stop or health need. History reads and exports
use a database engine of their own (a small pool, statement timeouts: ``backend/store/db.py``) and threads
of their own: history reads queue on a limiter the size of that pool, not on the threads every other route
shares, and exports are encoded (CSV, NDJSON, Parquet, MCAP) on a bounded pool of export threads. Exports
are admitted here: at most ``max_total`` at once and ``max_per_client`` per client; the next one is
refused at once (429 for the client over its share, 503 when all are taken), with Retry-After, before
any work is done. An export writes into a bounded channel the HTTP response drains: a client that reads
slowly slows its export, one that stops reading is cut off by the response (``backend/api/exports.py``),
and either way the export's thread stops at its next write.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import IO, Any, TypeVar, cast

import anyio.to_thread
from anyio import CapacityLimiter
from sqlalchemy import Engine

from backend.core.errors import ServiceError

log = logging.getLogger(__name__)

T = TypeVar("T")

#: bytes an export hands to the response at a time, and how many such chunks may wait for the client
CHUNK_BYTES = 256 * 1024
QUEUE_CHUNKS = 4
_END = object()


class ExportCancelled(Exception):
    """The client went away or was cut off: the export stops writing."""


@dataclass
class ExportCounters:
    admitted: int = 0
    refused_client: int = 0
    refused_busy: int = 0
    cut_stalled: int = 0
    failed: int = 0


class ExportSlot:
    """One admitted export; ``release`` (idempotent) gives its place back."""

    def __init__(self, gate: ExportGate, client: str) -> None:
        self._gate = gate
        self.client = client
        self._released = False

    def release(self) -> None:
        if not self._released:
            self._released = True
            self._gate._release(self.client)


@dataclass
class ExportGate:
    """Admission of exports: per client and in all. Used on the event loop only (no lock)."""

    max_total: int
    max_per_client: int
    retry_after_s: int
    counters: ExportCounters = field(default_factory=ExportCounters)
    _running: dict[str, int] = field(default_factory=dict)

    @property
    def running(self) -> int:
        return sum(self._running.values())

    def admit(self, client: str) -> ExportSlot:
        """A slot, or a ServiceError (429 too_many_exports / 503 exports_busy) with Retry-After."""
        headers = {"Retry-After": str(self.retry_after_s)}
        mine = self._running.get(client, 0)
        if mine >= self.max_per_client:
            self.counters.refused_client += 1
            raise ServiceError(
                429,
                f"you have {mine} exports running, the most one client may (FLEET_EXPORT_MAX_PER_CLIENT="
                f"{self.max_per_client}): let one finish or cancel it, then retry after {self.retry_after_s} s",
                "too_many_exports",
                headers,
            )
        if self.running >= self.max_total:
            self.counters.refused_busy += 1
            raise ServiceError(
                503,
                f"the server is running {self.running} exports, its most (FLEET_EXPORT_MAX_CONCURRENT="
                f"{self.max_total}): retry after {self.retry_after_s} s",
                "exports_busy",
                headers,
            )
        self._running[client] = mine + 1
        self.counters.admitted += 1
        return ExportSlot(self, client)

    def _release(self, client: str) -> None:
        left = self._running.get(client, 0) - 1
        if left > 0:
            self._running[client] = left
        else:
            self._running.pop(client, None)

    def stats(self) -> dict[str, Any]:
        return {
            "running": self.running,
            "clients": len(self._running),
            "max_total": self.max_total,
            "max_per_client": self.max_per_client,
            **vars(self.counters),
        }


class _Channel:
    """Chunks from an export's thread to the event loop; at most ``size`` wait (the thread blocks then)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, size: int) -> None:
        self._loop = loop
        self._items: asyncio.Queue[Any] = asyncio.Queue()
        self._room = threading.Semaphore(size)
        self.cancelled = threading.Event()

    def put(self, item: Any) -> None:
        """On the export's thread; raises ExportCancelled once the response has gone."""
        while not self._room.acquire(timeout=0.5):
            if self.cancelled.is_set():
                raise ExportCancelled
        if self.cancelled.is_set():
            raise ExportCancelled
        try:
            self._loop.call_soon_threadsafe(self._items.put_nowait, item)
        except RuntimeError:  # the loop has closed (server stopping)
            raise ExportCancelled from None

    async def get(self) -> Any:
        item = await self._items.get()
        self._room.release()
        return item


class ChannelSink:
    """A write-only, non-seekable file whose bytes go to the channel in chunks of CHUNK_BYTES."""

    def __init__(self, channel: _Channel) -> None:
        self._channel = channel
        self._buf = bytearray()
        self._pos = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        n = len(data)
        self._buf += data
        self._pos += n
        if len(self._buf) >= CHUNK_BYTES:
            self._send()
        return n

    def _send(self) -> None:
        chunk, self._buf = bytes(self._buf), bytearray()
        self._channel.put(chunk)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self._buf:
            self._send()


class ExportStream:
    """What ``produce`` writes, on an export thread, as an async iterator of chunks for the response.
    ``cancel`` (or the iterator's end) stops the thread at its next write."""

    def __init__(self, produce: Callable[[IO[bytes]], object], pool: ThreadPoolExecutor, what: str) -> None:
        self._produce = produce
        self._pool = pool
        self._what = what
        self._channel: _Channel | None = None

    def cancel(self) -> None:
        if self._channel is not None:
            self._channel.cancelled.set()

    def __aiter__(self) -> AsyncIterator[bytes]:
        return self._chunks()

    async def _chunks(self) -> AsyncIterator[bytes]:
        channel = self._channel = _Channel(asyncio.get_running_loop(), QUEUE_CHUNKS)
        sink = ChannelSink(channel)

        def work() -> None:
            outcome: Any = _END
            try:
                self._produce(cast(IO[bytes], sink))
                sink.close()
            except ExportCancelled:
                return
            except Exception as exc:
                log.exception("%s failed", self._what)
                outcome = exc
            with contextlib.suppress(ExportCancelled):
                channel.put(outcome)

        self._pool.submit(work)
        try:
            while True:
                item = await channel.get()
                if item is _END:
                    return
                if isinstance(item, Exception):
                    raise item
                yield item
        finally:
            channel.cancelled.set()


class Readers:
    """The readers' engine, the limiter history reads queue on, the export threads and the export gate."""

    def __init__(
        self, *, engine: Engine, reads: int, gate: ExportGate, stall_timeout_s: float, statement_timeout_s: float
    ) -> None:
        self.engine = engine
        self.gate = gate
        self.stall_timeout_s = stall_timeout_s
        #: what the engine's statements may take (for messages; the engine enforces it)
        self.statement_timeout_s = statement_timeout_s
        self._limiter = CapacityLimiter(reads)
        self._pool = ThreadPoolExecutor(max_workers=gate.max_total, thread_name_prefix="export")

    async def run(self, fn: Callable[..., T], *args: Any) -> T:
        """A read on a thread, at most ``reads`` at once (the others wait here, taking no thread from the
        rest of the API)."""
        return await anyio.to_thread.run_sync(fn, *args, limiter=self._limiter)

    def stream(self, produce: Callable[[IO[bytes]], object], what: str) -> ExportStream:
        return ExportStream(produce, self._pool, what)

    def stats(self) -> dict[str, Any]:
        return {**self.gate.stats(), "reads_waiting": self._limiter.statistics().tasks_waiting}

    def close(self) -> None:
        """Server stop: exports still running stop at their next write; the engine's connections close."""
        self._pool.shutdown(wait=False, cancel_futures=True)
        self.engine.dispose()
