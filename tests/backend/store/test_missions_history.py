"""A mission's history read in order with the writes: ``GET /api/missions/{id}`` once showed a mission
``completed`` (in memory) without its ``completed`` transition, read before the writer had committed it."""

from __future__ import annotations

import threading
import time
from functools import partial

from sqlalchemy import Engine

from backend.store import missions as store
from backend.store.writer import BatchWriter


def _mission(mid: str, now: float) -> dict[str, object]:
    return {
        "id": mid,
        "name": "m",
        "type": "coverage",
        "state": "draft",
        "robots": ["r1"],
        "params": {},
        "plan": {},
        "progress": {},
        "created_by": "admin",
        "created_at": now,
        "updated_at": now,
    }


def _transition(mid: str, now: float, before: str, after: str) -> dict[str, object]:
    return {"mission_id": mid, "ts": now, "from_state": before, "to_state": after, "actor": "system", "reason": ""}


def test_a_history_read_on_the_writer_sees_the_transition_queued_before_it(engine: Engine) -> None:
    writer = BatchWriter(engine)
    writer.start()
    try:
        now = time.time()
        writer.submit(store.insert_mission(_mission("m1", now), _transition("m1", now, "", "draft")), want_result=True)
        flushed = writer.submit(lambda conn: None, want_result=True)
        assert flushed is not None and flushed.result(10) is None  # the draft is committed
        gate = threading.Event()
        writer.submit(lambda conn: gate.wait(10), after_rows=False)  # the writer is busy for a moment
        completed = store.update_mission("m1", {"state": "completed"}, _transition("m1", now + 1, "draft", "completed"))
        writer.submit(completed, after_rows=False)
        read = writer.submit(partial(store.history_on, mission_id="m1"), want_result=True, after_rows=False)
        assert read is not None
        # a direct read now misses the transition: what the route did
        direct, _ = store.history(engine, "m1")
        assert [t["to_state"] for t in direct] == ["draft"]
        gate.set()
        transitions, _ = read.result(10)
        assert [t["to_state"] for t in transitions] == ["draft", "completed"]
    finally:
        writer.stop()
