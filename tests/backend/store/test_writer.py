"""The batch writer's promises to the broker: an ack marker is released only after everything queued before
it is committed; a database that is away holds the acks back and the rows and writes are retried, not lost;
rows the database refuses are dropped one by one without blocking the rest; what had to be given up (a full
queue, rows trimmed from the retry buffer, a full retry queue) is never acked, and the broker delivers it
again once the writer has caught up."""

from __future__ import annotations

import asyncio
import threading
from typing import Any

import orjson
from sqlalchemy import Engine, text

from backend.comms.mqtt_bridge import InboundMessage, MqttBridge, Subscription
from backend.services.telemetry.ingest import telemetry_row
from backend.store import audit as audit_store
from backend.store import repository as repo
from backend.store.writer import BatchWriter, StoreUnavailable
from fleet_protocol import encode_telemetry
from tests.support.dbfault import database_away
from tests.support.mqtt import MqttProbe
from tests.support.procs import Broker, wait_for, wait_until


def _rows(robot: str, n: int, start: int = 0) -> list[dict[str, Any]]:
    return [telemetry_row(robot, "position", 1000.0 + i, i, {"x": float(i), "y": 0.0}) for i in range(start, start + n)]


def _count(engine, robot: str) -> int:  # type: ignore[no-untyped-def]
    with engine.connect() as conn:
        return int(conn.execute(text("SELECT count(*) FROM telemetry WHERE robot_id = :r"), {"r": robot}).scalar_one())


def test_acks_follow_the_commit(engine):
    seen: list[tuple[list[Any], int]] = []

    def on_acks(tokens: list[Any]) -> None:
        seen.append((tokens, _count(engine, "w1")))  # what a fresh connection sees when the ack goes out

    writer = BatchWriter(engine, batch_rows=10_000, interval_s=5.0, on_acks=on_acks)
    writer.start()
    try:
        for r in _rows("w1", 250):
            writer.submit_telemetry(r)
        assert writer.submit_ack([(1, 1), (1, 2)])
        # group commit: the marker commits the batch at once instead of waiting the 5 s interval
        wait_for(lambda: seen, 3, what="acks")
        assert seen == [([(1, 1), (1, 2)], 250)]
        # an ack with nothing pending goes out at once; ops keep their order with rows
        assert writer.submit_ack([(1, 3)])
        wait_for(lambda: len(seen) == 2, 3)
        assert seen[1] == ([(1, 3)], 250)
    finally:
        writer.stop()
    assert writer.stats()["acks"] == 3 and writer.stats()["rows_written"] == 250
    with engine.connect() as conn:  # the minutes the rows touched are marked for the rollup
        marks = conn.execute(text("SELECT minute_ts FROM telemetry_dirty WHERE robot_id = 'w1' ORDER BY 1"))
        assert [m for (m,) in marks] == sorted({(1000.0 + i) // 60 * 60 for i in range(250)})


def test_database_away_holds_acks_then_retries(database_url):
    """The telemetry table is locked by another session: the batch fails, is retried, and only then acked."""
    acks: list[Any] = []
    with database_away(database_url) as (engine, release):
        writer = BatchWriter(engine, batch_rows=100, interval_s=0.01, on_acks=acks.extend)
        writer.start()
        try:
            for r in _rows("w2", 300):
                writer.submit_telemetry(r)
            writer.submit_ack([(1, 7)])
            wait_for(lambda: writer.retries >= 2, 10, what="retries while locked")
            assert acks == [] and writer.rows_dropped == 0
            release()
            wait_for(lambda: acks == [(1, 7)], 15, what="ack after the lock is gone")
            assert _count(engine, "w2") == 300
        finally:
            writer.stop()


def _stored_writes(engine: Engine) -> tuple[list[str], list[str], list[str]]:
    with engine.connect() as conn:
        audit = [a for (a,) in conn.execute(text("SELECT action FROM audit ORDER BY id"))]
        commands = [c for (c,) in conn.execute(text("SELECT id FROM commands ORDER BY ts"))]
        events = [k for (k,) in conn.execute(text("SELECT kind FROM events WHERE kind LIKE 'estop%' ORDER BY id"))]
    return audit, commands, events


def _audit(action: str) -> Any:
    return audit_store.insert_audit(
        {"ts": 1000.0, "actor": "ops", "actor_name": "ops", "token_id": None, "client": "", "action": action,
         "robot_id": "w6", "detail": {}}
    )  # fmt: skip


def _command(command_id: str, ts: float) -> Any:
    return repo.insert_command(
        {"id": command_id, "robot_id": "w6", "command": "stop", "args": {}, "source": "rest", "ts": ts,
         "ttl_s": 5.0, "status": "sent", "reason": "", "updated_at": ts}
    )  # fmt: skip


def test_writes_wait_out_the_outage_in_order_and_are_stored(database_url):
    """An audit row, a command and its update, and an e-stop event submitted while the database is away are
    retried in their order and stored once it is back; the acks behind them wait for them."""
    acks: list[Any] = []
    with database_away(database_url) as (engine, release):
        writer = BatchWriter(engine, interval_s=0.01, on_acks=acks.extend)
        writer.start()
        try:
            done = writer.submit(_audit("command"), want_result=True, after_rows=False)
            writer.submit(_command("c-1", 1000.0), after_rows=False)
            writer.submit(repo.update_command("c-1", "done", "", 1001.0))  # only after its insert
            writer.submit(repo.insert_event(1000.0, "estop", None, {"id": "e-1"}))
            writer.submit_ack([(1, 1)])
            wait_for(lambda: writer.stats()["ops_retrying"] == 4 and writer.retries >= 2, 10, what="writes held")
            assert acks == [] and done is not None and not done.done()
            release()
            wait_for(lambda: acks == [(1, 1)], 15, what="the ack once the writes are stored")
            assert done.result(1) is None
            with engine.connect() as conn:
                status = conn.execute(text("SELECT status FROM commands WHERE id = 'c-1'")).scalar_one()
        finally:
            writer.stop()
    assert _stored_writes(engine) == (["command"], ["c-1"], ["estop"]) and status == "done"
    assert writer.stats()["ops_dropped"] == 0 and writer.stats()["ops_refused"] == 0


def test_a_full_retry_queue_gives_writes_up_explicitly(database_url):
    """Bounded: past ``retry_max`` waiting writes the next are given up at once, their callers told
    (StoreUnavailable), counted, and the ack of the messages that caused them withheld, never sent."""
    acks: list[Any] = []
    withheld: list[Any] = []
    with database_away(database_url) as (engine, release):
        writer = BatchWriter(engine, interval_s=0.01, on_acks=acks.extend, retry_max=2, on_withheld=withheld.extend)
        writer.start()
        try:
            kept = [writer.submit(_command(f"k-{i}", 1000.0 + i), want_result=True, after_rows=False) for i in (1, 2)]
            writer.submit_ack([(1, 1)])
            lost = [writer.submit(_command(f"l-{i}", 2000.0 + i), want_result=True, after_rows=False) for i in (1, 2)]
            writer.submit_ack([(1, 2)])
            wait_for(lambda: withheld, 10, what="the second ack withheld")
            for fut in lost:
                assert fut is not None and isinstance(fut.exception(5), StoreUnavailable)
            assert writer.ops_dropped == 2 and acks == []
            release()
            wait_for(lambda: acks, 15, what="the first ack once its writes are stored")
            assert all(fut is not None and fut.result(1) is None for fut in kept)
        finally:
            writer.stop()
    assert acks == [(1, 1)] and withheld == [(1, 2)] and writer.acks_withheld == 1
    assert _stored_writes(engine)[1] == ["k-1", "k-2"]


def test_refused_rows_are_dropped_alone(engine):
    acks: list[Any] = []
    writer = BatchWriter(engine, batch_rows=1000, interval_s=0.05, on_acks=acks.extend)
    writer.start()
    try:
        rows = _rows("w3", 50)
        rows[20] = dict(rows[20], payload=None)  # NOT NULL: the database refuses this one row
        for r in rows:
            writer.submit_telemetry(r)
        writer.submit_ack([(1, 1)])
        wait_for(lambda: acks, 10, what="ack")
    finally:
        writer.stop()
    assert _count(engine, "w3") == 49 and writer.rows_rejected == 1 and writer.rows_dropped == 0
    assert acks == [(1, 1)]  # acked: a redelivery would be refused the same way


def test_a_dropped_row_withholds_its_ack(engine):
    acks: list[Any] = []
    gate = threading.Event()
    busy = threading.Event()

    def slow_op(conn: Any) -> None:
        busy.set()
        gate.wait(10)

    writer = BatchWriter(engine, batch_rows=1000, interval_s=0.05, queue_max=100, on_acks=acks.extend)
    writer.start()
    try:
        writer.submit(slow_op)
        assert busy.wait(10)  # the writer is busy in it: the queue fills up
        accepted = [writer.submit_telemetry(r) for r in _rows("w4", 150)]
        assert accepted.count(False) == writer.rows_dropped > 0
        assert writer.submit_ack([(1, 1)]) is False  # never acked: the broker keeps the message
        gate.set()
        wait_for(lambda: writer.stats()["queued"] == 0, 10, what="queue drained")
        assert writer.submit_ack([(1, 2)]) is True  # later messages are acked again
        wait_for(lambda: acks == [(1, 2)], 10, what="next ack")
    finally:
        gate.set()
        writer.stop()
    assert writer.acks_withheld == 1


def _stored_seqs(engine: Engine, robot: str) -> list[int]:
    with engine.connect() as conn:
        rows = conn.execute(text("SELECT seq FROM telemetry WHERE robot_id = :r ORDER BY seq"), {"r": robot})
        return [int(seq) for (seq,) in rows]


def test_rows_trimmed_while_the_database_is_away_are_not_acked_and_come_again(broker: Broker, database_url):
    """A real broker, bridge and writer: 600 messages arrive while the database is away and the retry buffer
    holds 100 rows, so the oldest are trimmed. Their acks are withheld; once the database is back and the
    writer caught up, the bridge reconnects, the broker delivers them again, and every seq is stored once."""
    sent = 600
    with database_away(database_url) as (engine, release):
        bridge: MqttBridge | None = None

        def on_messages(batch: list[InboundMessage]) -> None:
            rows = []
            for m in batch:
                body = orjson.loads(m.payload)
                rows.append(telemetry_row("trim-1", "position", body["ts"], body["seq"], body["data"], m.received))
            writer.submit_rows(rows)

        writer = BatchWriter(
            engine,
            batch_rows=50,
            interval_s=0.01,
            queue_max=100,
            on_acks=lambda tokens: bridge.ack(tokens) if bridge else None,
            on_withheld=lambda tokens: bridge.withhold(tokens) if bridge else None,
        )

        async def scenario() -> dict[str, Any]:
            nonlocal bridge
            bridge = MqttBridge(
                broker.url,
                [Subscription("fleet/+/telemetry/#", 1)],
                on_messages,
                client_id="writer-trim-test",
                on_ack_marker=writer.submit_ack,
                redeliver_when=writer.caught_up,
            )
            writer.start()
            bridge.start(asyncio.get_running_loop())
            try:
                await wait_until(lambda: bridge is not None and bridge.connected, what="connected")
                await asyncio.to_thread(_publish_burst, broker, sent)
                await wait_until(lambda: writer.rows_dropped > 0 and writer.acks_withheld > 0, 15, what="trimmed")
                assert bridge.stats()["redelivery_reconnects"] == 0  # not while the database is away
                release()
                await wait_until(lambda: len(_stored_seqs(engine, "trim-1")) == sent, 30, 0.2, what="every seq")
                await wait_until(lambda: bridge is not None and bridge.connected, what="connected again")
                return bridge.stats()
            finally:
                await bridge.stop()
                await asyncio.to_thread(writer.stop)

        stats = asyncio.run(scenario())
        assert _stored_seqs(engine, "trim-1") == list(range(sent))
    assert stats["redelivery_reconnects"] >= 1 and stats["acks_withheld_now"] == 0


def _publish_burst(broker: Broker, n: int) -> None:
    """QoS 1 without waiting for each PUBACK (all in flight at once), then for the last."""
    probe = MqttProbe(broker.host, broker.port)
    try:
        infos = [
            probe.client.publish(
                "fleet/trim-1/telemetry/position", encode_telemetry(seq, {"x": float(seq), "y": 0.0}, 1000.0 + seq), 1
            )
            for seq in range(n)
        ]
        for info in infos:
            info.wait_for_publish(10)
    finally:
        probe.close()
