"""The motor watchdog: a thread, outside the agent's event loop, that zeroes the motors when their lease runs out.

The command loop stops the motors when a drive's deadline passes (the deadman). That only works while the
loop runs: a stalled loop, a deadlock or a handler stuck in I/O leaves the last set-points on. So every drive
also gives the motors a *lease* (the drive's remaining time plus a margin); this thread sleeps until the
lease ends and, unless the loop refreshed it in time, stops the motors itself. It needs the GIL, so it acts
right after a stop-the-world pause (a long garbage collection) rather than during it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger(__name__)

#: Lease beyond a drive's own end. Small on purpose: a trip can only come after the drive should have ended
#: anyway (a loop that late is stalled), and the rest of the promised ``duration_s + 0.2 s`` (0.15 s) is
#: left for the thread's wake-up on a busy machine (measured: up to 0.13 s late at a load of 7 on 2 cores).
WATCHDOG_MARGIN_S = 0.05


class MotorWatchdog:
    """Owns the lock every motor call takes, so a trip never interleaves with a set from the loop."""

    def __init__(self, stop: Callable[[], None], clock: Callable[[], float] = time.monotonic) -> None:
        self._stop = stop
        self._clock = clock
        self.lock = threading.RLock()
        self._cond = threading.Condition(self.lock)
        self._deadline: float | None = None
        self._closed = False
        self._thread: threading.Thread | None = None
        self.trips = 0  # times the watchdog, not the loop, stopped the motors

    def arm(self, lease_s: float) -> None:
        """Motors may stay on for ``lease_s`` from now unless armed again; call with :attr:`lock` held."""
        with self._cond:
            self._deadline = self._clock() + lease_s
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="motor-watchdog", daemon=True)
                self._thread.start()
            self._cond.notify()

    def disarm(self) -> None:
        with self._cond:
            self._deadline = None
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._deadline = None
            self._cond.notify()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)

    def _run(self) -> None:
        with self._cond:
            while not self._closed:
                if self._deadline is None:
                    self._cond.wait()
                    continue
                late = self._clock() - self._deadline
                if late < 0:
                    self._cond.wait(-late)
                    continue
                self._deadline = None
                self.trips += 1
                try:
                    self._stop()
                except Exception:  # keep watching: the next drive arms it again
                    log.exception("motor watchdog: stopping the motors failed")
                log.warning(
                    "motor watchdog: the command loop did not refresh the motors in time; motors zeroed "
                    "(%.3f s after the lease ended)",
                    late,
                )
