"""Small bounded pools for CPU work the event loop must not do: mission planning (and re-planning, and the
coverage picture) and password checks (scrypt) each get threads of their own.

Not the loop's default executor (``asyncio.to_thread``) nor the threads routes share
(``run_in_threadpool``): those serve the database reads, and a burst of plans or logins there would make
every read wait behind CPU work. A pool has a few threads and a bounded queue; a job that finds the queue
full is refused at once (503 ``<name>_busy``) instead of piling up. The work a single job may do is bounded
by its caller before it is submitted (the missions' limits: backend/services/missions/limits.py).
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from backend.core.errors import ServiceError

T = TypeVar("T")


class WorkPool:
    """``workers`` threads named ``{name}-N``; at most ``queue_max`` jobs waiting for one of them."""

    def __init__(self, name: str, *, workers: int, queue_max: int) -> None:
        self.name = name
        self.workers = workers
        self.queue_max = queue_max
        self._executor = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=name)
        self._lock = threading.Lock()
        self._pending = 0  # submitted, not finished (running + waiting)
        #: jobs run to the end (an exception counts), refused for a full queue; seconds of work done
        self.done = 0
        self.refused = 0
        self.busy_s = 0.0
        self.longest_s = 0.0

    async def run(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` on one of the pool's threads; 503 at once when ``queue_max`` jobs already wait."""
        return await self._submit(fn, args, refuse=True)

    async def run_queued(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` on one of the pool's threads, waiting its turn however long the queue: for the
        server's own work (a re-plan after a robot dropped out), whose count is bounded where it comes from."""
        return await self._submit(fn, args, refuse=False)

    async def _submit(self, fn: Callable[..., T], args: tuple[Any, ...], refuse: bool) -> T:
        with self._lock:
            if refuse and self._pending >= self.workers + self.queue_max:
                self.refused += 1
                raise ServiceError(
                    503,
                    f"the {self.name} is busy ({self._pending} jobs running or waiting): try again in a moment",
                    f"{self.name}_busy",
                    headers={"Retry-After": "1"},
                )
            self._pending += 1
        try:
            future = self._executor.submit(self._timed, fn, args)
        except RuntimeError:  # closed: the server is stopping
            self._finished(None)
            raise ServiceError(503, f"the {self.name} is closed: the server is stopping", "shutting_down") from None
        future.add_done_callback(self._finished)  # a job still counts while it runs, even if its caller left
        return await asyncio.wrap_future(future)

    def _finished(self, _future: object) -> None:
        with self._lock:
            self._pending -= 1

    def _timed(self, fn: Callable[..., T], args: tuple[Any, ...]) -> T:
        t0 = time.perf_counter()
        try:
            return fn(*args)
        finally:
            took = time.perf_counter() - t0
            with self._lock:
                self.done += 1
                self.busy_s += took
                self.longest_s = max(self.longest_s, took)

    def stats(self) -> dict[str, float | int]:
        with self._lock:
            return {
                "workers": self.workers,
                "queue_max": self.queue_max,
                "pending": self._pending,
                "done": self.done,
                "refused": self.refused,
                "busy_s": round(self.busy_s, 3),
                "longest_s": round(self.longest_s, 3),
            }

    def close(self) -> None:
        """Wait for the running jobs (each bounded) and drop the waiting ones."""
        self._executor.shutdown(wait=True, cancel_futures=True)
