"""The hook a mission service uses: every alarm transition reaches a subscriber, and ``critical_of`` lists a
robot's open critical alarms (on a real SQLite database through the real writer thread)."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from pathlib import Path

from backend.core.config import Settings
from backend.schemas import AlarmPublic
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.services.safety.alarms import AlarmService
from backend.store.db import create_db_engine, upgrade_to_head
from backend.store.writer import BatchWriter


async def _until(predicate, timeout: float = 5.0) -> None:
    deadline = asyncio.get_running_loop().time() + timeout
    while not predicate():
        assert asyncio.get_running_loop().time() < deadline, "timed out"
        await asyncio.sleep(0.01)


def _run(tmp_path: Path, scenario: Callable[[AlarmService], Awaitable[None]]) -> None:
    """``scenario`` with an alarm service on a real SQLite database through the real writer thread."""
    engine = create_db_engine(Settings(database_url=f"sqlite:///{tmp_path / 'a.db'}"))
    upgrade_to_head(engine)
    writer = BatchWriter(engine)
    writer.start()
    hub = LiveHub()
    try:
        asyncio.run(scenario(AlarmService(writer=writer, hub=hub, registry=Registry(writer, hub))))
    finally:
        writer.stop()
        engine.dispose()
    assert writer.errors == 0


def test_subscribers_see_every_transition_and_critical_alarms_are_listed(tmp_path: Path) -> None:
    async def scenario(alarms: AlarmService) -> None:
        raised: list[tuple[str, str]] = []
        alarms.on_raise(lambda robot_id, kind: raised.append((robot_id, kind)))
        seen: list[tuple[str | None, str, str]] = []

        def listener(alarm: AlarmPublic) -> None:
            seen.append((alarm.robot_id, alarm.kind, alarm.state))

        def broken(alarm: AlarmPublic) -> None:
            raise RuntimeError("a listener that fails")

        alarms.subscribe(broken)  # first: the others still hear of it
        unsubscribe = alarms.subscribe(listener)
        alarms.on_health("m1", {"battery_pct": 50.0, "cpu_temp_c": 90.0})  # cpu_hot: a warning
        await _until(lambda: ("m1", "cpu_hot", "active") in seen)
        assert alarms.critical_of("m1") == []  # a warning is not critical
        alarms.on_health("m1", {"battery_pct": 3.0, "motor_fault": True})
        await _until(lambda: {("m1", "battery_critical", "active"), ("m1", "motor_fault", "active")} <= set(seen))
        assert sorted(a.kind for a in alarms.critical_of("m1")) == ["battery_critical", "motor_fault"]
        assert alarms.critical_of("m2") == []
        fault = next(a for a in alarms.critical_of("m1") if a.kind == "motor_fault")
        assert await alarms.ack(fault.id, "alice") is not None  # acknowledged: still open, still critical
        assert ("m1", "motor_fault", "acknowledged") in seen
        assert "motor_fault" in [a.kind for a in alarms.critical_of("m1")]
        alarms.on_health("m1", {"battery_pct": 80.0, "motor_fault": False, "cpu_temp_c": 40.0})
        assert {("m1", "battery_critical", "cleared"), ("m1", "motor_fault", "cleared")} <= set(seen)
        assert alarms.critical_of("m1") == []
        unsubscribe()
        n = len(seen)
        alarms.on_health("m1", {"cpu_temp_c": 95.0})
        await _until(lambda: alarms.of_robot("m1") != [])
        assert len(seen) == n  # unsubscribed
        # the raise hook (the command service stops a critical battery through it) heard each raise once
        kinds = [kind for _, kind in raised]
        assert sorted(set(kinds)) == ["battery_critical", "battery_low", "cpu_hot", "motor_fault"]
        assert kinds.count("battery_critical") == 1  # heard once, at the moment it was raised
        assert kinds[-1] == "cpu_hot" and kinds.count("cpu_hot") == 2  # raised again after it cleared

    _run(tmp_path, scenario)


def test_a_clear_heard_while_the_raise_is_stored_is_not_lost(tmp_path: Path) -> None:
    """A robot whose battery reads 3 % and then 90 % before the alarm's row is committed: the alarm is raised,
    then cleared (a robot that reports only on change would otherwise keep it open for good). A reading that
    goes back down again before the commit wins: the alarm stays."""

    async def scenario(alarms: AlarmService) -> None:
        seen: list[tuple[str | None, str, str]] = []
        alarms.subscribe(lambda a: seen.append((a.robot_id, a.kind, a.state)))
        # one loop turn: the writer's commits reach the loop only after it (call_soon_threadsafe)
        alarms.on_health("m1", {"battery_pct": 3.0})
        alarms.on_health("m1", {"battery_pct": 90.0})
        assert alarms.of_robot("m1") == []  # nothing stored yet: the clears wait for their raises
        await _until(lambda: ("m1", "battery_low", "cleared") in seen and ("m1", "battery_critical", "cleared") in seen)
        assert alarms.of_robot("m1") == []
        for kind in ("battery_critical", "battery_low"):
            assert [s for r, k, s in seen if k == kind] == ["active", "cleared"]
        # down, up, down again before the commit: the newest reading (3 %) wins
        alarms.on_health("m2", {"battery_pct": 3.0})
        alarms.on_health("m2", {"battery_pct": 90.0})
        alarms.on_health("m2", {"battery_pct": 3.0})
        await _until(lambda: {("m2", "battery_critical", "active"), ("m2", "battery_low", "active")} <= set(seen))
        # a clear kept by mistake would have followed each raise in the same callback, before this line
        assert sorted(a.kind for a in alarms.of_robot("m2")) == ["battery_critical", "battery_low"]
        assert [s for r, k, s in seen if r == "m2" and k == "battery_critical"] == ["active"]

    _run(tmp_path, scenario)
