"""Test helpers for the server suite: a robot played by an MQTT probe, a WebSocket collector."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import orjson
import websockets

from fleet_protocol import SEED_COMMANDS, Topics, encode_telemetry
from tests.support.mqtt import MqttProbe, Received
from tests.support.procs import ServerProcess

TOPICS = Topics()


class ProbeRobot:
    """A robot simulated at the MQTT level: precise control over every status, telemetry and ack."""

    def __init__(
        self,
        make_probe: Callable[..., MqttProbe],
        robot_id: str,
        commands: tuple[str, ...] | list[str] = SEED_COMMANDS,
        sensors: tuple[str, ...] = ("position",),
    ):
        self.robot_id = robot_id
        self.commands = list(commands)
        self.sensors = list(sensors)
        self.probe = make_probe(TOPICS.cmd(robot_id), TOPICS.estop())

    def status(self, online: bool = True, **extra: Any) -> None:
        payload = {
            "online": online,
            "ts": time.time(),
            "agent_version": "probe-1",
            "capabilities": {"sensors": self.sensors, "commands": self.commands},
            **extra,
        }
        self.probe.publish(TOPICS.status(self.robot_id), orjson.dumps(payload), retain=True)

    def telemetry(self, seq: int, data: dict[str, Any], stream: str = "position", ts: float | None = None) -> None:
        self.probe.publish(TOPICS.telemetry(self.robot_id, stream), encode_telemetry(seq, data, ts))

    def next_command(self, timeout: float = 5.0, after: int = 0) -> dict[str, Any]:
        topic = TOPICS.cmd(self.robot_id)
        msg = self.probe.wait(lambda m: m.topic == topic and not m.retain, timeout)
        return orjson.loads(msg.payload)  # type: ignore[no-any-return]

    def commands_received(self) -> list[dict[str, Any]]:
        topic = TOPICS.cmd(self.robot_id)
        return [orjson.loads(m.payload) for m in self.probe.matching(lambda m: m.topic == topic)]

    def ack(self, command_id: str, status: str, reason: str = "") -> None:
        payload = {"id": command_id, "status": status, "reason": reason, "ts": time.time()}
        self.probe.publish(TOPICS.ack(self.robot_id), orjson.dumps(payload))

    def wait_estop(self, engaged: bool = True, timeout: float = 5.0) -> Received:
        return self.probe.wait(
            lambda m: m.topic == TOPICS.estop() and orjson.loads(m.payload)["engaged"] is engaged, timeout
        )


def register_legacy(client: Any, robot_id: str, listens_on: str = "shared") -> dict[str, Any]:
    """Name a robot on the old framework (an admin's step): only registered robots are heard on its topics."""
    r = client.put(f"/api/robots/{robot_id}/legacy", json={"listens_on": listens_on})
    assert r.status_code == 200, r.text
    return r.json()  # type: ignore[no-any-return]


def driveable(robot: dict[str, Any]) -> bool:
    """Online with a fix, and its safety filter hears the fleet's poses (its first health report says so):
    a robot driven sooner creeps (docs/autonomy.md), and a test measuring the drive saw too little of it."""
    early = ("no health report", "hears no fleet poses")
    return (
        bool(robot["online"])
        and robot["position"] is not None
        and not any(reason.startswith(early) for reason in robot["not_ready_reasons"])
    )


def writer_idle(writer: dict[str, int]) -> bool:
    """The server's writer (``/api/stats``' ``writer``) has committed, dropped or refused every row it was given."""
    done = writer["rows_written"] + writer["rows_dropped"] + writer["rows_rejected"]
    return writer["queued"] == 0 and done == writer["rows_submitted"]


#: a robot without a fix for this long has stopped sending (robots send ten a second)
QUIET_S = 1.0


def wait_stored(get: Callable[[str], Any], robots: list[str], since: float, timeout: float = 15.0) -> None:
    """Until what the robots sent before ``since`` (wall clock) is stored: each robot's latest fix is newer (a
    robot's messages arrive in order), or none came for a second (it stopped sending: an old-framework robot
    whose operator let go), and the writer has committed what came. ``get``: a path -> its JSON."""
    from tests.support.procs import wait_for

    def heard_through(fix: dict[str, Any] | None) -> bool:
        return fix is None or fix["ts"] >= since or time.time() - fix["ts"] > QUIET_S

    def caught_up() -> bool:
        fixes = [(get(f"/api/robots/{rid}") or {}).get("position") for rid in robots]
        return all(heard_through(fix) for fix in fixes) and writer_idle(get("/api/stats")["writer"])

    wait_for(caught_up, timeout, what=f"{robots}' messages before {since:.2f} stored")


def wait_robot(
    client: Any, robot_id: str, predicate: Callable[[dict[str, Any]], bool], timeout: float = 10.0
) -> dict[str, Any]:
    from tests.support.procs import wait_for

    def _check() -> dict[str, Any] | None:
        r = client.get(f"/api/robots/{robot_id}")
        if r.status_code == 200 and predicate(r.json()):
            return r.json()  # type: ignore[no-any-return]
        return None

    return wait_for(_check, timeout, what=f"robot {robot_id} state")  # type: ignore[no-any-return]


async def ws_collect(
    url: str,
    subscribe: dict[str, Any],
    until: Callable[[list[dict[str, Any]]], bool],
    timeout: float = 10.0,
    on_open: Callable[[], Any] | None = None,
) -> tuple[list[dict[str, Any]], list[str]]:
    """Subscribe, then collect messages until ``until(messages)``; also returns the raw frames."""
    messages: list[dict[str, Any]] = []
    frames: list[str] = []
    async with websockets.connect(url) as ws:
        await ws.send(orjson.dumps(subscribe).decode())
        if on_open is not None:
            await asyncio.to_thread(on_open)
        deadline = time.monotonic() + timeout
        while not until(messages):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"websocket condition not met in {timeout}s; got {messages[-5:]}")
            frame = await asyncio.wait_for(ws.recv(), remaining)
            assert isinstance(frame, str), "server frames are text"
            frames.append(frame)
            batch = orjson.loads(frame)
            assert isinstance(batch, list), "each frame is a JSON array"
            messages.extend(batch)
    return messages, frames


def publish_burst(robot: ProbeRobot, stream: str, items: list[tuple[int, float, dict[str, Any]]]) -> None:
    """QoS 1 without waiting for each PUBACK (waits for the last one)."""
    topic = TOPICS.telemetry(robot.robot_id, stream)
    info = None
    for seq, ts, data in items:
        info = robot.probe.client.publish(topic, encode_telemetry(seq, data, ts), qos=1)
    assert info is not None
    info.wait_for_publish(10)


@contextlib.contextmanager
def dispatcher_rig(db: Path, camera: bool = False) -> Iterator[tuple[Any, Any, Any]]:
    """The server's message path without its network: (dispatcher, registry, rejects) on a SQLite file,
    with an MQTT bridge that is never started (publishes go nowhere). Fails if the writer saw errors."""
    from backend.comms.mqtt_bridge import MqttBridge
    from backend.core.config import Settings
    from backend.core.rejects import InboundRejects
    from backend.services.dispatcher import Dispatcher
    from backend.services.fleet.registry import Registry
    from backend.services.legacy.bridge import LegacyAdapter
    from backend.services.live.camera import CameraRelay
    from backend.services.live.hub import LiveHub
    from backend.services.telemetry.ingest import TelemetryIngest
    from backend.store.db import create_db_engine, upgrade_to_head
    from backend.store.writer import BatchWriter
    from tests.backend.factories import command_side

    engine = create_db_engine(Settings(database_url=f"sqlite:///{db}"))
    upgrade_to_head(engine)
    writer = BatchWriter(engine)
    writer.start()
    hub = LiveHub()
    registry = Registry(writer, hub)
    ingest = TelemetryIngest(registry, writer, hub, TOPICS)
    rejects = InboundRejects()
    bridge = MqttBridge("mqtt://127.0.0.1:1", [], lambda batch: None)
    commands, estop, holds, relay = command_side(registry, bridge, TOPICS, writer, hub)
    legacy = LegacyAdapter(registry, ingest, rejects, relay=relay, holds=holds)
    dispatcher = Dispatcher(
        TOPICS,
        registry,
        ingest,
        commands,
        estop,
        rejects,
        legacy.handle,
        camera=CameraRelay() if camera else None,
        holds=holds,
    )
    try:
        yield dispatcher, registry, rejects
    finally:
        writer.stop()
        engine.dispose()
    assert writer.errors == 0


def operator_token(server: ServerProcess, name: str) -> tuple[str, str]:
    """An operator API token made by the admin: (secret, its lease holder id)."""
    with server.client() as c:
        r = c.post("/api/tokens", json={"name": name, "role": "operator"})
        assert r.status_code == 201, r.text
        return r.json()["token"], f"token:{r.json()['id']}"


def audit_trail(server: ServerProcess, **params: Any) -> list[dict[str, Any]]:
    """The audit trail (``GET /api/audit`` as the admin, filtered by ``params``), oldest first."""
    with server.client() as c:
        r = c.get("/api/audit", params={"limit": 1000, **params})
        assert r.status_code == 200, r.text
        return list(reversed(r.json()))
