"""Commands are published before their row is committed, so a robot's ack can overtake the commit.

On the replica that sent the command the ack finds it in memory; on another replica (which only has the
database) the ack is tried again until the row is there. Either way it is stored once and told live.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from pathlib import Path

import orjson
import pytest
from sqlalchemy import Engine

from backend.comms.mqtt_bridge import MqttBridge
from backend.core.config import Settings
from backend.services.control import tracking as tracking_module
from backend.services.control.commands import CommandService
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.store import repository as repo
from backend.store.db import create_db_engine, upgrade_to_head
from backend.store.writer import BatchWriter
from fleet_protocol import Ack, AckStatus, Topics
from tests.backend.factories import command_side
from tests.support.procs import wait_until


def test_an_ack_that_overtakes_the_commit_on_another_replica_is_stored_once(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(tracking_module, "UNKNOWN_ACK_RETRY_S", (0.05, 0.2, 0.5))
    engine = create_db_engine(Settings(database_url=f"sqlite:///{tmp_path / 'fleet.db'}"))
    upgrade_to_head(engine)
    writer = BatchWriter(engine)
    writer.start()
    try:
        hub = LiveHub()
        bridge = MqttBridge("mqtt://127.0.0.1:1", [], lambda batch: None)  # never started
        service = command_side(Registry(writer, hub), bridge, Topics(), writer, hub)[0]
        now = time.time()

        async def scenario() -> list[dict]:
            frames: list[dict] = []

            async def send(frame: str) -> None:
                frames.extend(orjson.loads(frame))

            client = hub.add(send)
            client.subscribe(["*"], ["*"])
            sender = asyncio.create_task(client.run())
            # replica B: the robot's ack arrives before replica A has committed the command
            known = service.on_ack("r1", Ack(id="cmd-1", status=AckStatus.DONE, ts=now), received=now)
            assert known is False
            # the first try found nothing: a retry is scheduled
            await wait_until(lambda: service._ack_retries_pending == 1, timeout=5, what="a retry scheduled")
            assert repo.get_command(engine, "cmd-1") is None
            # replica A's commit lands
            writer.submit(
                repo.insert_command(
                    {
                        "id": "cmd-1",
                        "robot_id": "r1",
                        "command": "stop",
                        "args": {},
                        "source": "test",
                        "ts": now,
                        "ttl_s": 1.0,
                        "status": "sent",
                        "reason": "",
                        "updated_at": now,
                    }
                )
            )

            def ack_stored() -> bool:
                stored = repo.get_command(engine, "cmd-1")
                return stored is not None and bool(stored.acks)

            await wait_until(ack_stored, timeout=5, what="the ack stored")
            # no retry is left that could apply it twice
            await wait_until(lambda: service._ack_retries_pending == 0, timeout=5, what="the retries over")
            sender.cancel()
            return frames

        frames = asyncio.run(scenario())
        stored = repo.get_command(engine, "cmd-1")
        assert stored is not None and stored.status == "done"
        assert [a.status for a in stored.acks] == ["done"]
        told = [f["command"] for f in frames if f.get("type") == "command"]
        assert told and told[-1]["id"] == "cmd-1" and told[-1]["status"] == "done"
    finally:
        writer.stop()
        engine.dispose()
    assert writer.errors == 0


@pytest.fixture
def stored(tmp_path: Path) -> Iterator[tuple[Engine, BatchWriter]]:
    """A migrated SQLite database and its running writer (no writer errors allowed)."""
    engine = create_db_engine(Settings(database_url=f"sqlite:///{tmp_path / 'fleet.db'}"))
    upgrade_to_head(engine)
    writer = BatchWriter(engine)
    writer.start()
    try:
        yield engine, writer
    finally:
        writer.stop()
        engine.dispose()
    assert writer.errors == 0


@pytest.fixture
def lookups(monkeypatch) -> list[str]:
    """The command id of every database lookup an unknown ack makes (first try and retries)."""
    calls: list[str] = []
    real = repo.apply_ack_if_known

    def counting(command_id: str, robot_id: str, ack: dict):  # type: ignore[no-untyped-def]
        calls.append(command_id)
        return real(command_id, robot_id, ack)

    monkeypatch.setattr(tracking_module.repo, "apply_ack_if_known", counting)
    return calls


def _service(writer: BatchWriter) -> CommandService:
    hub = LiveHub()
    bridge = MqttBridge("mqtt://127.0.0.1:1", [], lambda batch: None)  # never started
    return command_side(Registry(writer, hub), bridge, Topics(), writer, hub)[0]


def test_an_ack_for_a_command_nobody_sent_is_tried_a_few_times_then_dropped(stored, lookups, monkeypatch) -> None:
    monkeypatch.setattr(tracking_module, "UNKNOWN_ACK_RETRY_S", (0.02, 0.02))
    engine, writer = stored
    service = _service(writer)

    async def scenario() -> None:
        service.on_ack("r1", Ack(id="ghost", status=AckStatus.DONE, ts=time.time()), received=time.time())
        # the retries ran, and none is left to run (so no further lookup can come)
        await wait_until(lambda: len(lookups) >= 3 and service._ack_retries_pending == 0, timeout=5)

    asyncio.run(scenario())
    assert lookups == ["ghost"] * 3  # the first try and two retries, then it is left alone
    assert repo.get_command(engine, "ghost") is None
    assert service._ack_retries_pending == 0 and service.ack_retries_refused == 0


def test_acks_waiting_for_a_retry_are_bounded(stored, lookups, monkeypatch) -> None:
    """A robot acking made-up ids gets each looked up once, not four times, beyond the bound."""
    monkeypatch.setattr(tracking_module, "UNKNOWN_ACK_RETRY_S", (0.05, 0.05))
    monkeypatch.setattr(tracking_module, "MAX_PENDING_ACK_RETRIES", 2)
    service = _service(stored[1])

    async def scenario() -> None:
        for i in range(5):
            service.on_ack("r1", Ack(id=f"made-up-{i}", status=AckStatus.DONE, ts=time.time()), time.time())
        # the retries ran, and none is left to run (so no further lookup can come)
        await wait_until(lambda: len(lookups) >= 9 and service._ack_retries_pending == 0, timeout=5)

    asyncio.run(scenario())
    assert service.ack_retries_refused == 3
    assert len(lookups) == 5 + 2 * 2  # five first tries; two of them retried twice
    assert service._ack_retries_pending == 0


def test_a_command_is_listed_before_its_row_is_committed(tmp_path: Path, broker) -> None:
    """POST returns once the command is published, not once its row is committed: until the commit the
    robot's command list merges the in-memory record in (in time order, range and limit applied), and
    after it the command is listed once."""
    from backend.schemas import CommandCreate
    from fleet_protocol import Capabilities, Status

    engine = create_db_engine(Settings(database_url=f"sqlite:///{tmp_path / 'fleet.db'}"))
    upgrade_to_head(engine)
    writer = BatchWriter(engine)  # not started yet: nothing commits
    hub = LiveHub()
    registry = Registry(writer, hub)

    async def scenario() -> None:
        bridge = MqttBridge(broker.url, [], lambda batch: None, client_id="overlay-test")
        bridge.start(asyncio.get_running_loop())
        await wait_until(lambda: bridge.connected, timeout=5)
        try:
            service = command_side(registry, bridge, Topics(), writer, hub)[0]
            registry.apply_status(
                "r1", Status(online=True, ts=time.time(), capabilities=Capabilities(commands=["stop"])), time.time()
            )
            first = await service.create("r1", CommandCreate(command="stop"))
            await wait_until(lambda: time.time() > first.ts)  # the second command is the newer one
            second = await service.create("r1", CommandCreate(command="stop"))
            assert repo.list_commands(engine, "r1", 100, None, None) == []  # not committed
            listed = service.overlay([], "r1")
            assert [c.id for c in listed] == [second.id, first.id]  # newest first
            assert [c.id for c in service.overlay([], "r1", limit=1)] == [second.id]
            assert [c.id for c in service.overlay([], "r1", end=first.ts)] == [first.id]
            assert service.overlay([], "someone-else") == []
            writer.start()
            await wait_until(lambda: len(repo.list_commands(engine, "r1", 100, None, None)) == 2, timeout=5)
            rows = repo.list_commands(engine, "r1", 100, None, None)
            assert [c.id for c in service.overlay(rows, "r1")] == [second.id, first.id]  # each once
        finally:
            await bridge.stop()

    try:
        asyncio.run(scenario())
    finally:
        writer.stop()
        engine.dispose()
    assert writer.errors == 0
