"""A real agent answers gap repair requests from its replay ring, byte for byte, with the broker's ACL on:
with ``--replay-dir`` also for the run before a restart (the ring is on disk); without it, that run's
messages are gone after a restart and the agent says so (``unavailable``), which the server records as
lost. The "server" here is a client with the server's broker account."""

from __future__ import annotations

import uuid
from pathlib import Path

import orjson

from fleet_protocol import Topics
from tests.deploy.test_mosquitto import Client
from tests.support.procs import AgentProcess, wait_for
from tests.system.test_gap_repair import ROBOT_PASSWORD, SERVER_PASSWORD, BrokerRef, acl_broker

TOPICS = Topics()
ROBOTS = ("ring-disk", "ring-memory")


def _telemetry(spy: Client, robot_id: str) -> list[bytes]:
    with spy.cond:
        return [p for t, p in spy.got if t == TOPICS.telemetry(robot_id, "position")]


def _replies(spy: Client, request_id: str) -> list[bytes]:
    with spy.cond:
        return [p for t, p in spy.got if t.endswith("/repair/reply") and orjson.loads(p)["id"] == request_id]


def _ask(server: Client, spy: Client, robot_id: str, boot: str, first: int, last: int) -> list[bytes]:
    request_id = uuid.uuid4().hex[:16]
    body = {"id": request_id, "ts": 1.0, "boot": boot, "stream": "position", "ranges": [[first, last]]}
    server.publish(TOPICS.repair_request(robot_id), orjson.dumps(body))
    return wait_for(
        lambda: (r := _replies(spy, request_id)) and orjson.loads(r[-1])["final"] and r,
        10,  # type: ignore[no-any-return]
        what=f"the reply of {robot_id}",
    )


def test_an_agent_replays_its_previous_run_from_disk_and_says_when_it_cannot(tmp_path: Path) -> None:
    broker = acl_broker(tmp_path, ROBOTS)
    ref = BrokerRef(broker.port)
    spy = Client(
        broker.port,
        username="fleet-server",
        password=SERVER_PASSWORD,
        subscribe=("fleet/+/telemetry/position", "fleet/+/repair/reply"),
    )
    server = Client(broker.port, username="fleet-server", password=SERVER_PASSWORD)
    args = {"ring-disk": ["--replay-dir", str(tmp_path / "ring")], "ring-memory": []}

    def start(rid: str) -> AgentProcess:
        a = AgentProcess(
            rid,
            ref,
            tmp_path,
            ["--position-rate", "50", *args[rid]],  # type: ignore[arg-type]
            FLEET_AGENT_PASSWORD=ROBOT_PASSWORD,
        )
        a.start()
        return a

    agents: dict[str, AgentProcess] = {}
    try:
        spy.wait_connected()
        server.wait_connected()
        agents.update({rid: start(rid) for rid in ROBOTS})
        wait_for(lambda: all(len(_telemetry(spy, rid)) > 80 for rid in ROBOTS), 30, what="telemetry")
        first_run = {rid: {orjson.loads(p)["seq"]: p for p in _telemetry(spy, rid)} for rid in ROBOTS}
        boots = {rid: orjson.loads(next(iter(first_run[rid].values())))["boot"] for rid in ROBOTS}

        # while running: both replay exactly what they published
        for rid in ROBOTS:
            (reply,) = _ask(server, spy, rid, boots[rid], 10, 60)
            assert all(first_run[rid][seq] in reply for seq in range(10, 61))  # the published bytes, verbatim
            assert orjson.loads(reply)["unavailable"] == []

        for rid in ROBOTS:
            assert agents[rid].stop() == 0
            count = len(_telemetry(spy, rid))
            agents[rid] = start(rid)
            wait_for(lambda rid=rid, count=count: len(_telemetry(spy, rid)) > count + 10, 30, what="restarted")
            new_boot = orjson.loads(_telemetry(spy, rid)[-1])["boot"]
            assert new_boot != boots[rid] and orjson.loads(_telemetry(spy, rid)[-1])["seq"] < 40  # seq from 0 again

        # after the restart: from disk, still byte for byte; from memory only, gone, and said so
        (reply,) = _ask(server, spy, "ring-disk", boots["ring-disk"], 10, 60)
        assert all(first_run["ring-disk"][seq] in reply for seq in range(10, 61))
        assert orjson.loads(reply)["unavailable"] == []
        (reply,) = _ask(server, spy, "ring-memory", boots["ring-memory"], 10, 60)
        assert orjson.loads(reply)["messages"] == [] and orjson.loads(reply)["unavailable"] == [[10, 60]]
    finally:
        for a in agents.values():
            a.stop()
        spy.close()
        server.close()
        broker.close()
