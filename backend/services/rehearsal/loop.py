"""An asyncio event loop on virtual time: it never sleeps, it jumps.

Whenever nothing is ready to run, a normal loop waits in ``select`` for the next timer; this one moves its
clock to that timer at once. Every ``asyncio.sleep``, ``call_later`` and timeout of the code it runs (the
mission service's tick, the formation driver's poll, the robots' supervision and deadman) then takes no wall
time, and the order of events is the order of their virtual times: the same inputs give the same run.

The same technique as aiotools' ``VirtualClock`` (lablup/aiotools), without patching a running loop: the
loop's ``time`` is the virtual clock and its selector never blocks. Nothing here may wait for a thread or a
socket: a twin runs its planning inline (a thread's result would arrive at a virtual time that depends on
the machine's load).
"""

from __future__ import annotations

import asyncio
import selectors
from typing import Any


class _JumpingSelector(selectors.DefaultSelector):
    """Polls (timeout 0) and moves the loop's clock by the timeout it was asked to wait."""

    def __init__(self) -> None:
        super().__init__()
        self.loop: VirtualTimeLoop | None = None

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        assert self.loop is not None
        if timeout is None:  # nothing ready and no timer: a real loop would wait for I/O that never comes
            raise RuntimeError("virtual-time loop: nothing scheduled, the run cannot go on")
        if timeout > 0:
            self.loop.advance(timeout)
        events: list[tuple[selectors.SelectorKey, int]] = super().select(0)
        return events


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    """``time()`` is virtual, starting at ``start``; see the module's docstring."""

    def __init__(self, start: float = 0.0) -> None:
        selector = _JumpingSelector()
        super().__init__(selector)
        selector.loop = self
        self._virtual = start

    def time(self) -> float:
        return self._virtual

    def advance(self, seconds: float) -> None:
        self._virtual += seconds


def run_virtual(main: Any, start: float = 0.0) -> Any:
    """Run the coroutine ``main`` to its end on a fresh :class:`VirtualTimeLoop`."""
    loop = VirtualTimeLoop(start)
    try:
        return loop.run_until_complete(main)
    finally:
        loop.close()
