"""Queued logging (the server's): lines still reach stderr, whole, from the writer thread."""

from __future__ import annotations

import json
import logging
import queue
import subprocess
import sys

from backend.core.logging import BoundedQueueHandler

SCRIPT = """
import logging
from backend.core.logging import setup_logging
setup_logging("INFO", "json", queued=True)
log = logging.getLogger("fleet.test")
items = ["before"]
log.info("items %s", items, extra={"robot_id": "r1"})
items.append("after")  # changed once logged: the line shows the value at the time of the call
try:
    1 / 0
except ZeroDivisionError:
    log.exception("it failed")
log.debug("below the level")
"""


def test_queued_logging_writes_every_line_with_its_context_and_traceback_before_exit() -> None:
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=30, check=True)
    lines = [json.loads(line) for line in done.stderr.splitlines()]
    assert [e["msg"] for e in lines] == ["items ['before']", "it failed"]
    assert lines[0]["robot_id"] == "r1" and lines[0]["logger"] == "fleet.test"
    assert "ZeroDivisionError" in lines[1]["exc"]


def test_a_full_log_queue_drops_and_counts_instead_of_blocking() -> None:
    handler = BoundedQueueHandler(queue.Queue(maxsize=1))
    record = logging.LogRecord("fleet.test", logging.INFO, __file__, 1, "n=%d", (1,), None)
    handler.handle(record)
    handler.handle(record)
    assert handler.dropped == 1
    assert handler.queue.get_nowait().getMessage() == "n=1"
