"""Exponential backoff for retry loops (broker reconnects, database retries, sensor restarts)."""

from __future__ import annotations


class Backoff:
    """Delays ``initial``, ``initial * factor``, ... capped at ``maximum``; :meth:`reset` after a success.

    Not thread-safe: each retry loop owns its own."""

    __slots__ = ("_delay", "factor", "initial", "maximum")

    def __init__(self, initial: float, maximum: float, factor: float = 2.0) -> None:
        if not 0 < initial <= maximum or factor < 1:
            raise ValueError(f"backoff needs 0 < initial <= maximum and factor >= 1: {initial}, {maximum}, {factor}")
        self.initial = initial
        self.maximum = maximum
        self.factor = factor
        self._delay = initial

    @property
    def delay(self) -> float:
        """What the next failure waits."""
        return self._delay

    def next(self) -> float:
        """The delay to wait now; the one after grows by ``factor`` (up to ``maximum``)."""
        delay = self._delay
        self._delay = min(self._delay * self.factor, self.maximum)
        return delay

    def reset(self) -> None:
        self._delay = self.initial
