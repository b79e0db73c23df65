"""Logging setup (stderr) and a per-key rate-limited warning logger for bad input."""

from __future__ import annotations

import logging
import sys
import threading
import time

import orjson

#: ``extra=`` keys copied into JSON log lines, so a log search can follow one robot or one command
CONTEXT_KEYS = ("robot_id", "command_id", "stream", "reason", "client")


class JsonFormatter(logging.Formatter):
    """One JSON object per line (ts, level, logger, msg, and robot_id/command_id when given)."""

    def format(self, record: logging.LogRecord) -> str:
        entry: dict[str, object] = {
            "ts": round(record.created, 6),
            "level": record.levelname,
            "logger": record.name,
            "msg": record.getMessage(),
        }
        for key in CONTEXT_KEYS:
            value = record.__dict__.get(key)
            if value is not None:
                entry[key] = value
        if record.exc_info:
            entry["exc"] = self.formatException(record.exc_info)
        return orjson.dumps(entry, default=str).decode()


def setup_logging(level: str, fmt: str = "text") -> None:
    """``fmt`` "json" for log shippers (one object per line), "text" for people."""
    handler = logging.StreamHandler(sys.stderr)
    if fmt == "json":
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=level.upper(), handlers=[handler], force=True)
    logging.getLogger("alembic.runtime.plugins").setLevel(logging.WARNING)


class RateLimitedLogger:
    """Logs at most one WARNING per key per ``interval_s``; reports how many were suppressed.

    Bad input can arrive at thousands of messages per second; logging each would drown the log.
    """

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
