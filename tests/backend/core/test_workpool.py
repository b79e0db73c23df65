"""A work pool runs its jobs on threads of its own (never the event loop's, never the default executor's that
serves database reads), at most ``workers`` at once, and refuses a job at once (503) when ``queue_max`` more
already wait; the server's own work (``run_queued``) waits its turn instead."""

from __future__ import annotations

import asyncio
import threading

import pytest

from backend.core.errors import ServiceError
from backend.core.workpool import WorkPool


def test_jobs_run_on_the_pools_threads_and_a_full_queue_is_refused_at_once() -> None:
    pool = WorkPool("planner", workers=2, queue_max=1)
    release = threading.Event()
    running: list[str] = []

    def job() -> str:
        running.append(threading.current_thread().name)
        release.wait(10)
        return threading.current_thread().name

    async def scenario() -> tuple[list[str], str]:
        loop_thread = threading.current_thread().name
        jobs = [asyncio.ensure_future(pool.run(job)) for _ in range(3)]  # two run, one waits
        while len(running) < 2 or pool.stats()["pending"] < 3:
            await asyncio.sleep(0.01)
        with pytest.raises(ServiceError) as refused:
            await pool.run(job)
        assert (refused.value.status_code, refused.value.code) == (503, "planner_busy")
        assert refused.value.headers == {"Retry-After": "1"}
        queued = asyncio.ensure_future(pool.run_queued(job))  # the server's own work: never refused
        await asyncio.sleep(0.05)  # the window in which a third job could have started: it must not
        assert len(running) == 2, "no more than two at once"
        release.set()
        names = list(await asyncio.gather(*jobs, queued))
        return names, loop_thread

    names, loop_thread = asyncio.run(scenario())
    pool.close()
    assert len(names) == 4 and all(n.startswith("planner_") for n in names), names
    assert loop_thread not in names
    assert pool.stats()["done"] == 4 and pool.stats()["refused"] == 1 and pool.stats()["pending"] == 0


def test_a_closed_pool_refuses_and_its_threads_end() -> None:
    pool = WorkPool("passwords", workers=1, queue_max=1)

    async def scenario() -> None:
        assert await pool.run(lambda: 7) == 7
        pool.close()
        with pytest.raises(ServiceError) as refused:
            await pool.run(lambda: 8)
        assert (refused.value.status_code, refused.value.code) == (503, "shutting_down")

    asyncio.run(scenario())
    assert not [t for t in threading.enumerate() if t.name.startswith("passwords_")]
