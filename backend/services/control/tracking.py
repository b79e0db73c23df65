"""The in-memory record of a command this server sent: its public shape, whether a final ack came, and the
``?wait`` requests waiting for one."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

from backend.schemas import CommandPublic


@dataclass
class Tracked:
    cmd: CommandPublic
    #: a final ack (done, rejected, expired...) arrived
    final: bool = False
    #: ``?wait`` requests: plain futures resolved by the ack itself, so the request resumes on the next
    #: loop turn (``wait_for`` on an ``Event`` took three turns, each behind the fleet's telemetry)
    waiters: list[asyncio.Future[None]] = field(default_factory=list)

    def finish(self) -> None:
        self.final = True
        for waiter in self.waiters:
            wake(waiter)
        self.waiters.clear()


def wake(waiter: asyncio.Future[None]) -> None:
    """Resume a ``?wait`` request (final ack or its timeout, whichever comes first)."""
    if not waiter.done():
        waiter.set_result(None)
