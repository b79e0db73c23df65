"""Time as the motion runner sees it, injectable: the real clock on a robot, a virtual one in a twin.

Every read of time and every sleep of the runner (and of the supervision it keeps) goes through a
:class:`Clock`, so a digital twin can run the same control and supervision code faster than real time, or
step by step, without patching ``time`` or the event loop.
"""

from __future__ import annotations

import asyncio
import time
from typing import Protocol

from fleet_protocol import now


class Clock(Protocol):
    def monotonic(self) -> float:
        """Seconds that only go forward: fix ages, heartbeat silence, goal deadlines, report pacing."""
        ...

    def now(self) -> float:
        """Wall-clock epoch seconds, for the ``ts`` of what the runner sends (its acks)."""
        ...

    async def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of this clock's time (the supervision tick)."""
        ...


class SystemClock:
    """The real clock: ``time.monotonic``, the wire's wall clock and ``asyncio.sleep``."""

    def monotonic(self) -> float:
        return time.monotonic()

    def now(self) -> float:
        return now()

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(seconds)


SYSTEM_CLOCK = SystemClock()
