"""A logger that writes at most one WARNING per key and interval (bad input can arrive by the thousand)."""

from __future__ import annotations

import logging
import threading
import time


class RateLimitedLogger:
    """Logs at most one WARNING per key per ``interval_s``; reports how many were suppressed.

    Thread-safe (the server's MQTT loop and its writer thread both log through one)."""

    def __init__(self, logger: logging.Logger, interval_s: float = 5.0) -> None:
        self._logger = logger
        self._interval = interval_s
        self._lock = threading.Lock()
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def warning(self, key: str, msg: str, *args: object) -> int | None:
        """Returns None when suppressed, else how many similar messages were suppressed before this one."""
        now = time.monotonic()
        with self._lock:
            last = self._last.get(key)
            if last is not None and now - last < self._interval:
                self._suppressed[key] = self._suppressed.get(key, 0) + 1
                return None
            self._last[key] = now
            suppressed = self._suppressed.pop(key, 0)
        if suppressed:
            self._logger.warning(msg + " (%d similar suppressed)", *args, suppressed)
        else:
            self._logger.warning(msg, *args)
        return suppressed
