"""Nothing lost under faults (issue 6): real Mosquitto, real servers, real simulated agents at 50 Hz.

* kill -9 the server mid-stream, start it again: its MQTT session is persistent and telemetry is only
  PUBACKed after the database commit, so every seq of every stream is stored exactly once, no gap;
  SQLite passes ``PRAGMA integrity_check``.
* restart the broker: agents and server reconnect by themselves and the telemetry the agents buffered
  while the broker was away arrives; again every seq exactly once.
"""

from __future__ import annotations

import sqlite3
import time
from collections import defaultdict
from pathlib import Path

import orjson
from sqlalchemy import create_engine, make_url, text

from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker, ServerProcess, wait_for

ROBOTS = ("fault-a", "fault-b")
CLIENT_ID = "fleet-server-faults"


def _published_max(probe: MqttProbe) -> dict[tuple[str, str], int]:
    """Highest seq per (robot, stream) the broker delivered to an independent subscriber."""
    top: dict[tuple[str, str], int] = {}
    for m in probe.matching(lambda m: "/telemetry/" in m.topic):
        parts = m.topic.split("/")
        key = (parts[1], parts[3])
        top[key] = max(top.get(key, -1), int(orjson.loads(m.payload)["seq"]))
    return top


def _stored(database_url: str) -> dict[tuple[str, str], list[int]]:
    engine = create_engine(database_url)
    try:
        with engine.connect() as conn:
            rows = conn.execute(text("SELECT robot_id, stream, seq FROM telemetry ORDER BY robot_id, stream, seq"))
            out: dict[tuple[str, str], list[int]] = defaultdict(list)
            for robot_id, stream, seq in rows:
                out[(robot_id, stream)].append(int(seq))
            return dict(out)
    finally:
        engine.dispose()


def _assert_exactly_once(database_url: str, probe: MqttProbe, min_per_position: int) -> None:
    """Every seq the agents published (0..max) is stored exactly once, for every robot and stream."""
    published = _published_max(probe)
    assert {r for r, _ in published} == set(ROBOTS)

    def _complete() -> dict[tuple[str, str], list[int]] | None:
        stored = _stored(database_url)
        done = all(len(stored.get(k, [])) >= top + 1 for k, top in published.items())
        return stored if done else None

    stored = wait_for(_complete, 60, interval=0.5, what="every published seq stored")
    for key, top in published.items():
        seqs = stored[key]
        assert seqs == list(range(len(seqs))), f"{key}: gap or duplicate in stored seqs"
        assert len(seqs) >= top + 1
    for robot in ROBOTS:
        assert len(stored[(robot, "position")]) >= min_per_position


def _integrity_ok(database_url: str) -> None:
    url = make_url(database_url)
    if url.get_backend_name() != "sqlite":
        return
    con = sqlite3.connect(str(Path(url.database or "")))
    try:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    finally:
        con.close()


def _agents(spawn_agent) -> list[AgentProcess]:  # type: ignore[no-untyped-def]
    return [spawn_agent(r, "--position-rate", "50", "--imu-rate", "50") for r in ROBOTS]


def _position_count(server: ServerProcess, robot: str) -> int:
    with server.client() as c:
        streams = {s["stream"]: s for s in c.get(f"/api/robots/{robot}/streams").json()}
    return int(streams.get("position", {}).get("count", 0))


def test_server_kill_9_mid_stream_loses_nothing(broker, database_url, workdir, spawn_agent, mqtt_probe):
    probe = mqtt_probe("fleet/+/telemetry/#")
    first = ServerProcess(broker, database_url, workdir, FLEET_MQTT_CLIENT_ID=CLIENT_ID)
    first.start()
    second: ServerProcess | None = None
    try:
        agents = _agents(spawn_agent)
        wait_for(
            lambda: all(_position_count(first, r) > 100 for r in ROBOTS),
            30,
            interval=0.2,
            what="telemetry flowing into the first server",
        )
        first.kill()  # SIGKILL: no shutdown, rows in the writer queue and unacked messages are gone
        # the agents keep publishing and the broker queues for the server's session: the probe sees them
        published_before = len(probe.messages)
        wait_for(lambda: len(probe.messages) >= published_before + 100, 10, what="telemetry while the server is down")
        second = ServerProcess(broker, database_url, workdir, FLEET_MQTT_CLIENT_ID=CLIENT_ID)
        second.start()
        with second.client() as c:
            mqtt = wait_for(lambda: c.get("/api/stats").json()["mqtt"], 10, what="stats")
            assert mqtt["session_present"] is True and mqtt["client_id"] == CLIENT_ID
        wait_for(
            lambda: all(_position_count(second, r) > 400 for r in ROBOTS),
            30,
            interval=0.2,
            what="telemetry flowing into the restarted server",
        )
        for a in agents:
            a.stop()
        _assert_exactly_once(database_url, probe, min_per_position=400)
    finally:
        if second is not None:
            second.stop()
        first.stop()
    _integrity_ok(database_url)


def test_broker_restart_agents_and_server_reconnect(database_url, workdir, spawn_agent):
    # Persistence on, as the shipped deploy/mosquitto config: the server's session and what is queued for
    # it survive the broker restart.
    broker = Broker(workdir, extra_conf=f"persistence true\npersistence_location {workdir}/\n")
    broker.start()
    server = ServerProcess(broker, database_url, workdir, FLEET_MQTT_CLIENT_ID=CLIENT_ID)
    probe: MqttProbe | None = None
    agents: list[AgentProcess] = []
    try:
        server.start()
        # A persistent probe session too, so it also gets what was buffered during the outage.
        probe = MqttProbe(
            broker.host, broker.port, ["fleet/+/telemetry/#"], client_id="faults-probe", clean_session=False
        )
        agents = [AgentProcess(r, broker, workdir, ["--position-rate", "50", "--imu-rate", "50"]) for r in ROBOTS]
        for a in agents:
            a.start()
        wait_for(
            lambda: all(_position_count(server, r) > 100 for r in ROBOTS), 30, interval=0.2, what="telemetry flowing"
        )
        before = {r: _position_count(server, r) for r in ROBOTS}
        broker.stop()
        with server.client() as c:
            wait_for(lambda: c.get("/api/health").json()["mqtt"]["connected"] is False, 10, what="server sees it")
        time.sleep(2.0)  # the outage's length is the scenario under test: agents buffer their telemetry meanwhile
        broker.start()
        with server.client() as c:
            wait_for(
                lambda: c.get("/api/health").json()["mqtt"]["connected"] is True,
                20,
                interval=0.2,
                what="server reconnected by itself",
            )
            wait_for(
                lambda: all(c.get(f"/api/robots/{r}").json()["online"] for r in ROBOTS),
                20,
                interval=0.2,
                what="agents reconnected by themselves",
            )
        wait_for(
            lambda: all(_position_count(server, r) > before[r] + 200 for r in ROBOTS),
            30,
            interval=0.2,
            what="telemetry flowing again",
        )
        for a in agents:
            a.stop()
        _assert_exactly_once(database_url, probe, min_per_position=300)
    finally:
        for a in agents:
            a.stop()
        if probe is not None:
            probe.close()
        server.stop()
        broker.stop()
    _integrity_ok(database_url)
