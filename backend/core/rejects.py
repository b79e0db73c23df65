"""Counters of refused input (MQTT payloads, robot ids), exposed in /api/health and /api/stats."""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable
from typing import Any

from backend.core.logging import RateLimitedLogger

log = logging.getLogger("backend.rejects")


class InboundRejects:
    """Thread-safe: the MQTT thread and the event loop both count.

    ``on_logged`` (e.g. an events-table writer) is called, like the log, at most once per kind and reason
    per interval, with the number of similar rejects suppressed since the previous call.
    """

    def __init__(self, on_logged: Callable[[dict[str, Any]], object] | None = None) -> None:
        self._lock = threading.Lock()
        self._by_reason: Counter[str] = Counter()
        self._by_kind: Counter[str] = Counter()
        self._rl = RateLimitedLogger(log)
        self.on_logged = on_logged

    def reject(self, kind: str, reason: str, topic: str, detail: str = "") -> None:
        with self._lock:
            self._by_reason[reason] += 1
            self._by_kind[kind] += 1
        suppressed = self._rl.warning(
            f"{kind}:{reason}", "rejected %s message on %r: %s %s", kind, topic[:120], reason, detail[:200]
        )
        if suppressed is not None and self.on_logged is not None:
            self.on_logged(
                {
                    "kind": kind,
                    "reason": reason,
                    "topic": topic[:120],
                    "detail": detail[:200],
                    "suppressed_before": suppressed,
                }
            )

    def snapshot(self) -> dict[str, object]:
        with self._lock:
            return {
                "total": sum(self._by_reason.values()),
                "by_reason": dict(self._by_reason),
                "by_kind": dict(self._by_kind),
            }

    def count(self, reason: str) -> int:
        with self._lock:
            return self._by_reason[reason]
