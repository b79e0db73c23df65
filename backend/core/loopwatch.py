"""Event-loop stall watchdog: everything live (telemetry fan-out, command acks, the deadman's resends
from browsers) runs on one event loop, so a stall there is a stall of the whole fleet view.

A heartbeat callback on the loop stamps the time every ``interval_s``; a watchdog thread checks the stamp.
When the heartbeat is late by more than ``threshold_s``, the thread logs where the loop thread is stuck
(its current Python stack) once per stall, and the stall's length is recorded when the heartbeat comes
back. A stall caused by another thread holding the GIL shows the loop thread waiting at an innocent line;
the log then names the threads that were running Python code too.

A stall longer than ``alarm_s`` (0.2 s: the heartbeat, the REST e-stop and every live view waited that
long) is counted apart and handed to ``on_alarm`` on the loop once it is back: the server raises the
fleet-wide ``loop_stall`` alarm with it (services/container.py), and ``/metrics`` counts it
(``fleet_event_loop_stalls_total``).
"""

from __future__ import annotations

import asyncio
import logging
import sys
import threading
import time
import traceback
from collections.abc import Callable

log = logging.getLogger(__name__)

#: stack frames logged per thread (the innermost ones)
STACK_DEPTH = 12
#: a stall at least this long raises an alarm (seconds)
ALARM_S = 0.2


class LoopWatchdog:
    def __init__(
        self,
        interval_s: float = 0.01,
        threshold_s: float = 0.1,
        alarm_s: float = ALARM_S,
        on_alarm: Callable[[float], None] | None = None,
    ) -> None:
        self._interval = interval_s
        self._threshold = threshold_s
        self._alarm_s = alarm_s
        #: called on the loop with a stall's length (seconds) once it is over, for each stall over ``alarm_s``
        self._on_alarm = on_alarm
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread_id: int | None = None
        self._beat = time.monotonic()
        self._handle: asyncio.TimerHandle | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="loop-watchdog", daemon=True)
        self._in_stall = False
        self._logged_at = 0.0
        #: the longest the heartbeat has been late (ms), stall or not
        self.max_lag_ms = 0.0
        #: stalls longer than the threshold, the longest one (ms), and the last one's end (epoch seconds)
        self.stalls = 0
        self.max_stall_ms = 0.0
        self.last_stall_at: float | None = None
        #: stalls longer than ``alarm_s`` (each one alarmed)
        self.alarmed_stalls = 0

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Call on the loop's thread."""
        self._loop = loop
        self._loop_thread_id = threading.get_ident()
        self._beat = time.monotonic()
        self._handle = loop.call_later(self._interval, self._heartbeat)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._handle is not None:
            self._handle.cancel()
        if self._thread.is_alive():
            self._thread.join(1.0)

    def stats(self) -> dict[str, object]:
        return {
            "stalls": self.stalls,
            "max_stall_ms": round(self.max_stall_ms, 1),
            "max_lag_ms": round(self.max_lag_ms, 1),
            "last_stall_at": self.last_stall_at,
            "threshold_ms": self._threshold * 1000,
            "alarmed_stalls": self.alarmed_stalls,
            "alarm_ms": self._alarm_s * 1000,
        }

    # -- event loop ------------------------------------------------------------------------------------
    def _heartbeat(self) -> None:
        now = time.monotonic()
        late = now - self._beat - self._interval
        self.max_lag_ms = max(self.max_lag_ms, late * 1000)
        if late > self._threshold:
            self.stalls += 1
            self.max_stall_ms = max(self.max_stall_ms, late * 1000)
            self.last_stall_at = time.time()
            log.warning("event loop stalled for %.0f ms", late * 1000)
        self._beat = now
        self._in_stall = False
        assert self._loop is not None
        self._handle = self._loop.call_later(self._interval, self._heartbeat)
        if late >= self._alarm_s:
            self.alarmed_stalls += 1
            if self._on_alarm is not None:
                try:
                    self._on_alarm(late)
                except Exception:  # the alarm must never stop the heartbeat
                    log.exception("loop stall alarm failed")

    # -- watchdog thread -------------------------------------------------------------------------------
    def _watch(self) -> None:
        # twice per threshold is enough to catch a stall: waking every heartbeat interval would take the GIL
        # from the loop 100 times a second for nothing
        while not self._stop.wait(self._threshold / 2):
            late = time.monotonic() - self._beat - self._interval
            if late <= self._threshold or self._in_stall:
                continue
            self._in_stall = True
            now = time.monotonic()
            if now - self._logged_at < 10:  # at most one stack dump per 10 s
                continue
            self._logged_at = now
            try:
                log.warning("event loop stalled for more than %.0f ms; threads now:\n%s", late * 1000, self._stacks())
            except Exception:  # never let the watchdog die
                log.exception("loop watchdog failed")

    def _stacks(self) -> str:
        names = {t.ident: t.name for t in threading.enumerate()}
        parts = []
        for ident, frame in sys._current_frames().items():
            if ident == threading.get_ident():
                continue
            marker = " (event loop)" if ident == self._loop_thread_id else ""
            lines = traceback.format_stack(frame, limit=STACK_DEPTH)
            parts.append(f"--- {names.get(ident, ident)}{marker}\n" + "".join(lines).rstrip())
        return "\n".join(parts)
