"""No silent loss (issue 15): telemetry the broker drops is repaired end to end.

The shipped Mosquitto config with authentication and the shipped ACL on, but a queue of only 200
messages per client (``max_queued_messages 200``); the real server, whose in-flight window
(``FLEET_MQTT_RECEIVE_MAXIMUM``) is 100, so that what the broker holds for it while it cannot read is
300 messages; three real simulated agents publishing position at 100 Hz. The server is frozen with
SIGSTOP for 5 s of their telemetry (about 1,650 messages): the broker drops what does not fit, and
says so in its log. After SIGCONT the server must find the gaps, ask the agents for them over
``fleet/{id}/repair/request`` and store the replies: within 15 s every stream has 0 open and 0 lost gaps,
and the database holds exactly seq 0..N of every stream, each once.
"""

from __future__ import annotations

import os
import signal
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import httpx
import orjson
import pytest
from sqlalchemy import create_engine, text

from backend.core.broker_auth import set_broker_password
from tests.deploy.test_mosquitto import DEPLOY, Client, ShippedBroker
from tests.support.procs import AgentProcess, ServerProcess, wait_for

ROBOTS = ("gap-a", "gap-b", "gap-c")
RATE_HZ = 100
FREEZE_MESSAGES = 5 * RATE_HZ  # the freeze lasts as long as 5 s of a robot's position stream
QUEUE = 200
SERVER_PASSWORD = "server-password-0123456789"
ROBOT_PASSWORD = "robot-password-0123456789"
SHIPPED_QUEUE_LINE = "max_queued_messages 100000\n"


class BrokerRef:
    """What ServerProcess and AgentProcess need of a broker: its address (credentials go separately)."""

    def __init__(self, port: int) -> None:
        self.host, self.port, self.url = "127.0.0.1", port, f"mqtt://127.0.0.1:{port}"


def acl_broker(tmp_path: Path, robots: tuple[str, ...], queue: int | None = None) -> ShippedBroker:
    """deploy/mosquitto/ as shipped (auth on, acl.example) with accounts for the server and ``robots``,
    optionally with the queue cut to ``queue`` messages; started (the caller closes it)."""
    passwd = tmp_path / "passwd"
    set_broker_password(passwd, "fleet-server", SERVER_PASSWORD)
    for rid in robots:
        set_broker_password(passwd, rid, ROBOT_PASSWORD)
    files = {"passwd": passwd.read_text(), "acl": (DEPLOY / "mosquitto" / "acl.example").read_text()}
    b = ShippedBroker("auth", files)
    if queue is not None:
        conf = b.conf.read_text()
        assert SHIPPED_QUEUE_LINE in conf, "deploy/mosquitto/mosquitto.conf changed its queue line"
        b.conf.write_text(conf.replace(SHIPPED_QUEUE_LINE, f"max_queued_messages {queue}\n"))
    try:
        b.start()
    except BaseException:
        b.close()
        raise
    return b


@pytest.fixture
def small_queue_broker(tmp_path: Path) -> Iterator[ShippedBroker]:
    b = acl_broker(tmp_path, ROBOTS, QUEUE)
    try:
        yield b
    finally:
        b.close()


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


def _published_max(spy: Client) -> dict[tuple[str, str], int]:
    """Highest seq per (robot, stream) an independent subscriber saw."""
    with spy.cond:
        got = list(spy.got)
    top: dict[tuple[str, str], int] = {}
    for topic, payload in got:
        parts = topic.split("/")
        if len(parts) == 4 and parts[2] == "telemetry":
            key = (parts[1], parts[3])
            top[key] = max(top.get(key, -1), int(orjson.loads(payload)["seq"]))
    return top


def _streams(c: httpx.Client) -> dict[tuple[str, str], dict[str, object]]:
    out = {}
    for rid in ROBOTS:
        r = c.get(f"/api/robots/{rid}/streams")
        assert r.status_code == 200, r.text
        for s in r.json():
            out[(rid, s["stream"])] = s
    return out


def test_broker_drops_while_the_server_is_frozen_and_every_gap_is_repaired(
    small_queue_broker: ShippedBroker, database_url: str, tmp_path: Path
) -> None:
    broker = BrokerRef(small_queue_broker.port)
    server = ServerProcess(
        broker,
        database_url,
        tmp_path,  # type: ignore[arg-type]
        FLEET_MQTT_PASSWORD=SERVER_PASSWORD,
        FLEET_MQTT_RECEIVE_MAXIMUM="100",
        FLEET_MQTT_CLIENT_ID="fleet-server-gap-test",
    )
    spy = Client(
        small_queue_broker.port, username="fleet-server", password=SERVER_PASSWORD, subscribe=("fleet/+/telemetry/+",)
    )
    agents = [
        AgentProcess(
            rid,
            broker,
            tmp_path,
            ["--position-rate", str(RATE_HZ)],  # type: ignore[arg-type]
            FLEET_AGENT_PASSWORD=ROBOT_PASSWORD,
        )
        for rid in ROBOTS
    ]
    try:
        spy.wait_connected()
        server.start()
        for a in agents:
            a.start()
        with server.client() as c:
            wait_for(
                lambda: all(_published_max(spy).get((rid, "position"), -1) >= RATE_HZ for rid in ROBOTS),
                30,
                what="every agent publishing",
            )
            wait_for(
                lambda: {(rid, st) for rid in ROBOTS for st in ("position", "imu")} <= set(_streams(c)),
                30,
                what="the server storing every stream",
            )

            assert server.proc is not None
            at_stop = _published_max(spy)
            os.kill(server.proc.pid, signal.SIGSTOP)
            try:
                wait_for(
                    lambda: all(
                        _published_max(spy).get((rid, "position"), -1) >= at_stop[(rid, "position")] + FREEZE_MESSAGES
                        for rid in ROBOTS
                    ),
                    30,
                    what="5 s of telemetry published while the server is frozen",
                )
            finally:
                os.kill(server.proc.pid, signal.SIGCONT)
            resumed = time.monotonic()

            def _all_repaired() -> dict[tuple[str, str], dict[str, object]] | None:
                streams = _streams(c)
                clean = all(s["gaps_open"] == 0 and s["gaps_lost"] == 0 for s in streams.values())
                repaired = all(
                    int(streams[(rid, "position")]["gaps_repaired"]) > 0  # type: ignore[call-overload]
                    for rid in ROBOTS
                    if (rid, "position") in streams
                )
                return streams if clean and repaired else None

            streams = wait_for(_all_repaired, 15, interval=0.2, what="every gap repaired, none lost")
            took = time.monotonic() - resumed
            assert took <= 15.0
            repaired = sum(int(s["gaps_repaired"]) for s in streams.values())  # type: ignore[call-overload]
            print(f"\nrepaired {repaired} messages; all streams clean {took:.1f} s after SIGCONT")
            assert repaired > QUEUE  # far more than the queue: the broker dropped them, the agents replayed them
            metrics = c.get("/metrics").text
            assert 'fleet_telemetry_gaps_repaired_total{stream="position"}' in metrics
            wait_for(
                lambda: (
                    {
                        e["robot_id"]
                        for e in c.get("/api/events", params={"kind": "telemetry_repaired", "limit": 100}).json()
                    }
                    >= set(ROBOTS)
                ),
                10,
                what="repair events",
            )

        for a in agents:
            assert a.stop() == 0
        published = _published_max(spy)

        def _complete() -> dict[tuple[str, str], list[int]] | None:
            stored = _stored(database_url)
            return stored if all(len(stored.get(k, [])) >= top + 1 for k, top in published.items()) else None

        stored = wait_for(_complete, 30, interval=0.5, what="every published seq stored")
        assert {k[0] for k in stored} == set(ROBOTS)
        for key, seqs in stored.items():
            assert seqs == list(range(len(seqs))), f"{key}: stored seqs are not exactly 0..N once each"
            assert len(seqs) >= published.get(key, -1) + 1
        # the broker really dropped messages for the frozen server (its log is written out when it stops)
        small_queue_broker.stop()
        assert "Outgoing messages are being dropped for client fleet-server-gap-test" in small_queue_broker.output()
    finally:
        for a in agents:
            a.stop()
        server.stop()
        spy.close()
