"""What the database writer had to give up raises a fleet-wide event alarm (``AlarmService`` on its tick): writes
lost (critical) and telemetry not stored (warning). Raised once the writer can keep the alarm's own row: a
real writer over a database another session holds, then lets go."""

from __future__ import annotations

import asyncio
import time

from backend.schemas import AlarmPublic
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.services.safety.alarms import AlarmService
from backend.services.telemetry.ingest import telemetry_row
from backend.store import repository as repo
from backend.store.writer import BatchWriter
from tests.support.dbfault import database_away
from tests.support.procs import wait_until


def test_writes_given_up_and_rows_trimmed_raise_their_alarms_once_the_writer_has_room(database_url) -> None:
    seen: list[tuple[str | None, str, str, str]] = []
    with database_away(database_url) as (engine, release):
        writer = BatchWriter(engine, interval_s=0.01, queue_max=100, retry_max=1)
        writer.start()

        async def scenario() -> None:
            hub = LiveHub()
            alarms = AlarmService(writer=writer, hub=hub, registry=Registry(writer, hub))
            alarms.subscribe(lambda a: seen.append((a.robot_id, a.kind, a.state, a.message)))
            for i in range(3):  # one kept for a retry, two given up
                writer.submit(repo.insert_event(1000.0 + i, "reject", None, {"i": i}))
            writer.submit_rows(
                [telemetry_row("s1", "position", 1000.0 + i, i, {"x": 0.0, "y": 0.0}) for i in range(300)]
            )
            await wait_until(lambda: writer.ops_dropped == 2 and writer.rows_dropped == 200, 10, what="given up")
            alarms.tick(time.time())
            await asyncio.sleep(0.3)  # a raise would reach the writer now: it is full, so none is made
            assert not writer.has_room() and alarms.open == {} and seen == []
            release()
            await wait_until(writer.caught_up, 15, what="the writer caught up")
            alarms.tick(time.time())
            await wait_until(lambda: len(seen) == 2, 10, what="two alarms")
            alarms.tick(time.time())  # nothing more was given up: nothing new
            await asyncio.sleep(0.3)
            assert len(seen) == 2 and {a.kind: a.severity for a in alarms.open.values()} == {
                "store_writes_lost": "critical",
                "telemetry_not_stored": "warning",
            }
            assert all(isinstance(a, AlarmPublic) and a.robot_id is None for a in alarms.open.values())

        try:
            asyncio.run(scenario())
        finally:
            writer.stop()
    assert sorted((robot, kind, state) for robot, kind, state, _ in seen) == [
        (None, "store_writes_lost", "active"),
        (None, "telemetry_not_stored", "active"),
    ]
    messages = {kind: message for _, kind, _, message in seen}
    assert messages["store_writes_lost"].startswith("2 database writes given up")
    assert messages["telemetry_not_stored"].startswith("200 telemetry rows not stored")
