"""A repair reply whose rows the writer could not keep (the database away, its retry buffer full) is not
acked, and when the broker delivers it again its messages are stored, although the first delivery closed
their gap (a real writer over a database another session holds, then lets go)."""

from __future__ import annotations

import time
from typing import Any

from sqlalchemy import text

from backend.comms.mqtt_bridge import MqttBridge
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.services.telemetry.ingest import TelemetryIngest
from backend.services.telemetry.repair import GapRepair
from backend.store.writer import BatchWriter
from fleet_protocol import Topics, encode_telemetry
from fleet_protocol.repair import encode_repair_reply
from tests.support.dbfault import database_away
from tests.support.procs import wait_for

BOOT = "boot-r1"


def test_a_reply_delivered_again_after_its_rows_were_given_up_is_stored(database_url) -> None:
    acks: list[Any] = []
    withheld: list[Any] = []
    with database_away(database_url) as (engine, release):
        writer = BatchWriter(engine, interval_s=0.01, queue_max=100, on_acks=acks.extend, on_withheld=withheld.extend)
        writer.start()
        try:
            hub = LiveHub()
            registry = Registry(writer, hub)
            ingest = TelemetryIngest(registry, writer, hub, Topics(), buffered=True)
            never_started = MqttBridge("mqtt://127.0.0.1:1", [], lambda batch: None)  # publishes nothing here
            repair = GapRepair(registry=registry, ingest=ingest, publisher=never_started, topics=Topics())
            now = time.time()
            for seq in (0, 301):  # 1..300 missing
                repair.observe("r1", "position", BOOT, seq, now)
            envelopes = [encode_telemetry(s, {"x": float(s), "y": 0.0}, 1000.0 + s, BOOT) for s in range(1, 301)]
            reply = encode_repair_reply("req-1", BOOT, "position", envelopes, [], True)

            def deliver(token: tuple[int, int]) -> None:
                """What the dispatcher does with the reply, then the drain's ack marker."""
                repair.on_reply("r1", reply, time.time())
                ingest.drained([token])

            deliver((1, 1))  # the database is away: 100 rows kept, the 200 oldest trimmed, the ack withheld
            wait_for(lambda: withheld == [(1, 1)], 10, what="the reply's ack withheld")
            assert writer.rows_dropped == 200 and acks == []
            assert repair.stats()["open"] == 0  # its gap is closed all the same
            release()
            wait_for(writer.caught_up, 15, what="the writer caught up")
            deliver((2, 1))  # the broker's redelivery, on the next connection
            wait_for(lambda: acks == [(2, 1)], 10, what="the redelivered reply acked")
            with engine.connect() as conn:
                q = text("SELECT seq FROM telemetry WHERE robot_id = 'r1' ORDER BY seq")
                stored = [int(s) for (s,) in conn.execute(q)]
        finally:
            writer.stop()
    assert stored == list(range(1, 301))
    assert repair.stats()["repaired"] == 300  # counted once, on the first delivery
