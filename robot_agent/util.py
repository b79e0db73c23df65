"""Small helpers: counted, rate-limited warnings for bad input."""

from __future__ import annotations

import logging
import time
from collections import Counter


class RejectCounter:
    """Counts rejected inputs by reason and logs at most one warning per reason per ``interval_s``."""

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0) -> None:
        self.log = logger
        self.interval_s = interval_s
        self.counts: Counter[str] = Counter()
        self._last: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()

    def reject(self, reason: str, detail: str = "") -> None:
        self.counts[reason] += 1
        now = time.monotonic()
        last = self._last.get(reason)
        if last is not None and now - last < self.interval_s:
            self._suppressed[reason] += 1
            return
        self._last[reason] = now
        extra = (
            f" (+{self._suppressed.pop(reason)} more since last report)" if self._suppressed[reason] else ""
        )
        self.log.warning("rejected %s: %s%s [total %d]", reason, detail[:300], extra, self.counts[reason])

    @property
    def total(self) -> int:
        return sum(self.counts.values())
