"""Small helpers: counted, rate-limited warnings for bad input."""

from __future__ import annotations

import logging
from collections import Counter

from fleet_common.ratelimit import RateLimitedLogger


class RejectCounter:
    """Counts rejected inputs by reason and logs at most one warning per reason per ``interval_s``."""

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0) -> None:
        self.log = logger
        self.interval_s = interval_s
        self.counts: Counter[str] = Counter()
        self._rl = RateLimitedLogger(logger, interval_s)

    def reject(self, reason: str, detail: str = "") -> None:
        self.counts[reason] += 1
        self._rl.warning(reason, "rejected %s: %s [total %d]", reason, detail[:300], self.counts[reason])

    @property
    def total(self) -> int:
        return sum(self.counts.values())
