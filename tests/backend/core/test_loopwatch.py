"""The event-loop watchdog notices a blocked loop, says where it was blocked, and counts the stall; in the
server, a stall of 0.2 s or more raises the fleet-wide ``loop_stall`` alarm and is counted in /metrics."""

from __future__ import annotations

import asyncio
import logging
import os
import re
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from backend.core.loopwatch import LoopWatchdog
from tests.support.procs import Broker, ServerProcess, wait_for, wait_until


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


def _stalls(c: httpx.Client) -> float:
    found = re.search(r"^fleet_event_loop_stalls_total (\S+)$", c.get("/metrics").text, re.MULTILINE)
    assert found is not None, "the stall counter is exposed"
    return float(found.group(1))


def _stall_alarms(c: httpx.Client) -> list[dict[str, Any]]:
    return [a for a in c.get("/api/alarms", params={"state": "open"}).json() if a["kind"] == "loop_stall"]


@pytest.fixture
def stall_alarmed_server(broker: Broker, database_url: str, workdir: Path) -> Iterator[ServerProcess]:
    """A server with the shipped alarm threshold (0.2 s; the suite's servers use 5 s: tests/support/procs.py)."""
    s = ServerProcess(broker, database_url, workdir, FLEET_LOOP_STALL_ALARM_S="0.2")
    s.start()
    try:
        yield s
    finally:
        s.stop()


def test_a_stalled_server_loop_raises_an_alarm_and_is_counted(stall_alarmed_server: ServerProcess) -> None:
    """The whole server frozen for 0.5 s (SIGSTOP: what a VM pause or a CPU hog does to its loop): once it is
    back, an open ``loop_stall`` alarm (fleet-wide, with the stall's length) and the counter one up."""
    server = stall_alarmed_server
    assert server.proc is not None
    with server.client() as c:
        for alarm in _stall_alarms(c):  # a start on a loaded machine may stall already: seen to first
            assert c.post(f"/api/alarms/{alarm['id']}/ack").status_code == 200
        wait_for(lambda: not _stall_alarms(c), 10, what="no loop_stall alarm open")
        before = _stalls(c)
        os.kill(server.proc.pid, signal.SIGSTOP)
        try:
            time.sleep(0.5)  # the stall under test
        finally:
            os.kill(server.proc.pid, signal.SIGCONT)
        alarms = wait_for(lambda: _stall_alarms(c), 10, what="the loop_stall alarm")
        assert len(alarms) == 1 and alarms[0]["robot_id"] is None and alarms[0]["severity"] == "warning", alarms
        assert alarms[0]["detail"]["stall_ms"] >= 450, alarms
        assert "event loop stalled for" in alarms[0]["message"], alarms
        assert _stalls(c) >= before + 1
