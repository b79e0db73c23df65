"""Logging setup (stderr); the per-key rate-limited warning logger for bad input is fleet_common's."""

from __future__ import annotations

import atexit
import copy
import logging
import logging.handlers
import queue
import sys

import orjson

from fleet_common.ratelimit import RateLimitedLogger

__all__ = ["BoundedQueueHandler", "JsonFormatter", "RateLimitedLogger", "setup_logging"]

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


#: log records waiting for the writer thread (``setup_logging(queued=True)``); beyond it they are dropped
LOG_QUEUE_MAX = 10_000


class BoundedQueueHandler(logging.handlers.QueueHandler):
    """Hands records to a :class:`logging.handlers.QueueListener` thread; drops (and counts) records when
    its bounded queue is full rather than blocking the caller or growing without bound."""

    def __init__(self, q: queue.Queue[logging.LogRecord]) -> None:
        super().__init__(q)
        self.dropped = 0

    def prepare(self, record: logging.LogRecord) -> logging.LogRecord:
        """The message with its arguments merged now (they may change later); the formatting itself (and
        the traceback's) is left to the writer thread's handler."""
        record = copy.copy(record)
        record.msg = record.getMessage()
        record.args = None
        return record

    def enqueue(self, record: logging.LogRecord) -> None:
        try:
            self.queue.put_nowait(record)
        except queue.Full:
            self.dropped += 1


def setup_logging(level: str, fmt: str = "text", *, queued: bool = False) -> None:
    """``fmt`` "json" for log shippers (one object per line), "text" for people.

    ``queued=True`` (the server): the caller only merges each record's arguments; a thread of its own
    formats the records and writes them to stderr. A write on the event loop (an access-log line per
    request, before its response goes out) gave the GIL away mid-request to the MQTT or database thread:
    a few tenths of a millisecond of every command's round trip."""
    handler = logging.StreamHandler(sys.stderr)
    if fmt == "json":
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root_handler: logging.Handler = handler
    if queued:
        records: queue.Queue[logging.LogRecord] = queue.Queue(LOG_QUEUE_MAX)
        root_handler = BoundedQueueHandler(records)
        listener = logging.handlers.QueueListener(records, handler, respect_handler_level=True)
        listener.start()
        atexit.register(listener.stop)  # writes what is still queued
    logging.basicConfig(level=level.upper(), handlers=[root_handler], force=True)
    logging.getLogger("alembic.runtime.plugins").setLevel(logging.WARNING)
