"""The event-loop watchdog notices a blocked loop, says where it was blocked, and counts the stall."""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

from backend.core.loopwatch import LoopWatchdog
from tests.support.procs import wait_until


def _blocking_callback_for_the_watchdog_to_find() -> None:
    time.sleep(0.3)  # blocking the loop is the behaviour under test (a callback that never yields)


def test_a_blocked_loop_is_counted_and_logged_with_the_blocking_stack(caplog: pytest.LogCaptureFixture) -> None:
    watchdog = LoopWatchdog(interval_s=0.01, threshold_s=0.1)

    async def scenario() -> int:
        watchdog.start(asyncio.get_running_loop())
        try:
            await asyncio.sleep(0.1)  # the idle period under test: ten heartbeats of a loop that is free
            idle_stalls = int(watchdog.stats()["stalls"])  # type: ignore[call-overload]
            asyncio.get_running_loop().call_soon(_blocking_callback_for_the_watchdog_to_find)
            await wait_until(lambda: watchdog.stats()["stalls"] != 0, timeout=5, what="the stall counted")
            return idle_stalls
        finally:
            watchdog.stop()

    with caplog.at_level(logging.WARNING, logger="backend.core.loopwatch"):
        assert asyncio.run(scenario()) == 0  # an idle loop beats on time
    stats = watchdog.stats()
    assert stats["stalls"] == 1
    assert 250 <= float(stats["max_stall_ms"]) < 1000  # type: ignore[arg-type]
    stack_dumps = [r.getMessage() for r in caplog.records if "threads now" in r.getMessage()]
    assert len(stack_dumps) == 1
    assert "(event loop)" in stack_dumps[0] and "_blocking_callback_for_the_watchdog_to_find" in stack_dumps[0]
    assert any(
        "event loop stalled for" in r.getMessage() and "threads now" not in r.getMessage() for r in caplog.records
    )  # the stall's length, once the loop is back


def test_the_watchdog_thread_ends_with_stop() -> None:
    watchdog = LoopWatchdog(interval_s=0.01)

    async def scenario() -> None:
        watchdog.start(asyncio.get_running_loop())
        await wait_until(lambda: watchdog._thread.is_alive())  # running before the stop
        watchdog.stop()

    asyncio.run(scenario())
    assert not watchdog._thread.is_alive()
