"""Gap repair, case by case, against the real server behind the shipped Mosquitto with the ACL on. The
robot is a scripted MQTT client with a robot's account, so each test decides exactly what is lost, when
the original comes late and how (or whether) the robot answers the server's repair requests.

* a repair answered twice, and an original arriving late (before and after the repair), is stored once;
  repaired rows keep their original ``ts``; a bad message in a reply is refused and counted, the rest kept;
* a range the robot no longer has, a range of a run before the agent restarted, a robot that never
  answers and an agent that sends no boot id: each is recorded as lost, with its range and reason;
* a reply that does not parse is refused and counted; nothing else changes.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import orjson
import pytest

from fleet_protocol import Topics, encode_telemetry
from tests.deploy.test_mosquitto import Client, ShippedBroker
from tests.support.procs import ServerProcess, wait_for
from tests.system.test_gap_repair import ROBOT_PASSWORD, SERVER_PASSWORD, BrokerRef, acl_broker

TOPICS = Topics()
ROBOTS = ("case-1", "case-2", "case-3")


@pytest.fixture
def setup(tmp_path: Path, database_url: str) -> Iterator[tuple[ShippedBroker, ServerProcess, str]]:
    """The shipped broker with the ACL on, and the server (on SQLite, or PostgreSQL with --database)."""
    broker = acl_broker(tmp_path, ROBOTS)
    server = ServerProcess(
        BrokerRef(broker.port),
        database_url,
        tmp_path,  # type: ignore[arg-type]
        FLEET_MQTT_PASSWORD=SERVER_PASSWORD,
    )
    try:
        server.start()
        yield broker, server, database_url
    finally:
        server.stop()
        broker.close()


class ScriptedRobot:
    """A robot's account on the broker: publishes its status and telemetry, collects repair requests."""

    def __init__(self, port: int, robot_id: str) -> None:
        self.id = robot_id
        self.client = Client(
            port, username=robot_id, password=ROBOT_PASSWORD, subscribe=(TOPICS.repair_request(robot_id),)
        )
        self.client.wait_connected()
        self.sent: dict[tuple[str, str, int], bytes] = {}
        self.publish_status()

    def publish_status(self) -> None:
        status = {"online": True, "ts": time.time(), "capabilities": {"sensors": ["position"], "commands": []}}
        self.client.publish(TOPICS.status(self.id), orjson.dumps(status), retain=True)

    def send(
        self, boot: str | None, seqs: list[int] | range, drop: range | None = None, stream: str = "position"
    ) -> None:
        """Publish ``seqs`` in this order (a seq sent before goes again byte for byte); the ones in ``drop``
        are made (the robot keeps them) but the first time never reach the broker, as if it had dropped them."""
        dropped = set(drop or ())
        for seq in seqs:
            key = (boot or "", stream, seq)
            payload = self.sent.get(key) or encode_telemetry(seq, {"x": seq / 10, "y": 0.5}, ts=time.time(), boot=boot)
            self.sent[key] = payload
            if seq in dropped:
                dropped.discard(seq)
            else:
                self.client.publish(TOPICS.telemetry(self.id, stream), payload)

    def requests(self) -> list[dict[str, object]]:
        with self.client.cond:
            return [orjson.loads(p) for t, p in self.client.got if t == TOPICS.repair_request(self.id)]

    def wait_request(self, n: int = 1, timeout: float = 10.0) -> dict[str, object]:
        return wait_for(
            lambda: len(self.requests()) >= n and self.requests()[n - 1],
            timeout,
            what=f"repair request {n} to {self.id}",
        )  # type: ignore[no-any-return]

    def reply(
        self,
        req: dict[str, object],
        seqs: list[int],
        unavailable: list[list[int]] | None = None,
        corrupt: tuple[int, ...] = (),
    ) -> None:
        """Answer ``req`` with the kept messages ``seqs``; those in ``corrupt`` with a position that is not one."""
        boot, stream = str(req["boot"]), str(req["stream"])
        messages = [orjson.loads(self.sent[(boot, stream, s)]) for s in seqs]
        for m in messages:
            if m["seq"] in corrupt:
                m["data"] = {"x": "nope"}
        body = {
            "id": req["id"],
            "boot": boot,
            "stream": stream,
            "messages": messages,
            "unavailable": unavailable or [],
            "final": True,
        }
        self.client.publish(TOPICS.repair_reply(self.id), orjson.dumps(body))

    def close(self) -> None:
        self.client.close()


def _stream(c: httpx.Client, robot_id: str, stream: str = "position") -> dict[str, object]:
    r = c.get(f"/api/robots/{robot_id}/streams")
    assert r.status_code == 200, r.text
    return next((s for s in r.json() if s["stream"] == stream), {})


def _stored_rows(database_url: str, robot_id: str) -> list[tuple[int, float]]:
    from sqlalchemy import create_engine, text

    engine = create_engine(database_url)
    try:
        with engine.connect() as conn:
            q = text("SELECT seq, ts FROM telemetry WHERE robot_id = :r AND stream = 'position' ORDER BY seq, id")
            return [(int(s), float(t)) for s, t in conn.execute(q, {"r": robot_id})]
    finally:
        engine.dispose()


def test_a_gap_is_stored_once_when_answered_twice_and_when_the_original_comes_late(
    setup: tuple[ShippedBroker, ServerProcess, str],
) -> None:
    broker, server, database_url = setup
    robot = ScriptedRobot(broker.port, "case-1")
    try:
        robot.send("boot-a", [*range(0, 30), 12], drop=range(10, 20))  # 10..19 dropped; 12 comes late, at once
        req = robot.wait_request()
        assert req["boot"] == "boot-a" and req["stream"] == "position"
        assert req["ranges"] == [[10, 11], [13, 19]]  # the late original is not asked for
        robot.reply(req, list(range(10, 20)), corrupt=(13,))  # (12 again as well: not stored twice)
        robot.reply(req, list(range(10, 20)))  # the same answer twice (13 now fine: stored from this one)
        robot.send("boot-a", [15, 30])  # an original after its repair; then a new message
        with server.client() as c:
            s = wait_for(lambda: (s := _stream(c, "case-1")) and s.get("count") == 31 and s, 10, what="31 rows stored")
            assert (s["gaps_open"], s["gaps_repaired"], s["gaps_lost"]) == (0, 9, 0)
            assert s["open_ranges"] == [] and s["lost_ranges"] == [] and s["boot"] == "boot-a"
            rows = _stored_rows(database_url, "case-1")
            assert [seq for seq, _ in rows] == list(range(31))
            for seq, ts in rows:  # repaired rows keep the ts the robot first sent
                assert ts == orjson.loads(robot.sent[("boot-a", "position", seq)])["ts"]
            kinds = {e["kind"] for e in c.get("/api/events", params={"robot_id": "case-1"}).json()}
            assert {"telemetry_gap", "telemetry_repaired"} <= kinds
            stats = c.get("/api/stats").json()["gap_repair"]
            assert (stats["repaired"], stats["open"], stats["lost"], stats["replayed_refused"]) == (9, 0, 0, 1)
            assert stats["requests_sent"] == 1 and stats["replies"] == 2
            rejects = c.get("/api/health").json()["rejects"]["by_reason"]
            assert rejects.get("bad_replayed_telemetry") == 1  # the bad message, not the reply, was refused
            metrics = c.get("/metrics").text
            assert 'fleet_telemetry_gaps_repaired_total{stream="position"} 9.0' in metrics
            assert 'fleet_telemetry_gaps_open{stream="position"} 0.0' in metrics
        assert len(robot.requests()) == 1  # nothing left to ask
    finally:
        robot.close()


def test_gaps_that_cannot_be_repaired_are_recorded_as_lost_with_their_range_and_reason(
    setup: tuple[ShippedBroker, ServerProcess, str],
) -> None:
    broker, server, database_url = setup
    r1, r2, r3 = (ScriptedRobot(broker.port, rid) for rid in ROBOTS)
    try:
        # the robot no longer has the range
        r1.send("boot-a", range(0, 15), drop=range(5, 10))
        req = r1.wait_request()
        assert req["ranges"] == [[5, 9]]
        r1.reply(req, [7], unavailable=[[5, 6], [8, 9]])
        # a gap in a run that then ended: the agent restarted (new boot id, seq from 0) without it
        r1.send("boot-a", [20])
        r1.send("boot-b", range(0, 3))
        req = r1.wait_request(2)
        assert req["boot"] == "boot-a" and req["ranges"] == [[15, 19]]
        r1.reply(req, [], unavailable=[[15, 19]])
        # a robot that never answers: asked three times, then given up
        r2.send("boot-x", [0, 1, 5])
        # an agent without boot ids cannot be asked: lost at once
        r3.send(None, [0, 1, 4])
        with server.client() as c:
            s1 = wait_for(lambda: (s := _stream(c, "case-1")) and s.get("gaps_lost") == 9 and s, 10, what="r1 lost")
            assert (s1["gaps_open"], s1["gaps_repaired"], s1["boot"]) == (0, 1, "boot-b")
            assert [(g["boot"], g["first"], g["last"], g["reason"]) for g in s1["lost_ranges"]] == [
                ("boot-a", 5, 6, "unavailable"),
                ("boot-a", 8, 9, "unavailable"),
                ("boot-a", 15, 19, "agent_restarted"),
            ]
            s3 = wait_for(lambda: (s := _stream(c, "case-3")) and s.get("gaps_lost") and s, 10, what="r3 lost")
            assert (s3["gaps_lost"], s3["lost_ranges"][0]["reason"]) == (2, "no_boot_id")
            s2 = wait_for(lambda: (s := _stream(c, "case-2")) and s.get("gaps_open") and s, 10, what="r2 gap")
            assert s2["gaps_open"] == 3 and s2["open_ranges"] == [
                {"boot": "boot-x", "first": 2, "last": 4, "reason": None, "at": None}
            ]
            s2 = wait_for(
                lambda: (s := _stream(c, "case-2")) and s.get("gaps_lost") == 3 and s, 15, what="r2's gap given up"
            )
            assert s2["gaps_open"] == 0 and s2["lost_ranges"][0]["reason"] == "no_answer"
            assert len(r2.requests()) == 3
            assert r3.requests() == []  # (r1 and r2 were asked: r3 could have been)
            lost = [e for e in c.get("/api/events", params={"kind": "telemetry_lost"}).json()]
            assert {e["robot_id"] for e in lost} == set(ROBOTS)
            assert 'fleet_telemetry_gaps_lost_total{stream="position"} 14.0' in c.get("/metrics").text

            # a reply that does not parse is refused and counted, and changes nothing
            r1.client.publish(TOPICS.repair_reply("case-1"), b'{"id": "x", "boot": "boot-a", "stream": 3}')
            wait_for(
                lambda: c.get("/api/health").json()["rejects"]["by_reason"].get("bad_repair_reply") == 1,
                10,
                what="the bad reply counted",
            )
            assert _stream(c, "case-1")["gaps_lost"] == 9
        stored = sorted(seq for seq, _ in _stored_rows(database_url, "case-1"))
        assert stored == sorted([*range(0, 5), 7, *range(10, 15), 20, *range(0, 3)])  # boot-a, then boot-b
    finally:
        for r in (r1, r2, r3):
            r.close()


def test_a_run_that_lost_its_first_messages_is_repaired_and_a_server_restart_invents_no_gap(
    setup: tuple[ShippedBroker, ServerProcess, str],
) -> None:
    """An agent that connects while the server listens starts its run at seq 0, so a run first seen at
    seq 3 lost 0..2 and they are asked for. After a server restart the first message of a run the server
    sees can be anything (what came before is stored already): no gap, no request."""
    broker, server, database_url = setup
    robot = ScriptedRobot(broker.port, "case-1")  # its online status reaches the running server live
    try:
        robot.send("boot-a", range(0, 10), drop=range(0, 3))
        req = robot.wait_request()
        assert req["boot"] == "boot-a" and req["ranges"] == [[0, 2]]
        robot.reply(req, [0, 1, 2])
        with server.client() as c:
            wait_for(lambda: _stream(c, "case-1").get("gaps_repaired") == 3, 10, what="0..2 repaired")

        server.stop()
        robot.send("boot-a", range(10, 20))  # queued for the server's persistent session meanwhile
        server.start()
        robot.send("boot-a", range(20, 30))
        robot.publish_status()  # the agent's periodic status refresh: not a new connection
        robot.send("boot-a", range(5, 8), stream="sonar")  # a stream of the same run, first seen now
        with server.client() as c:
            s = wait_for(lambda: (s := _stream(c, "case-1")) and s.get("count") == 30 and s, 15, what="30 rows")
            assert (s["gaps"], s["gaps_open"], s["gaps_repaired"], s["gaps_lost"]) == (0, 0, 0, 0)
            sonar = wait_for(
                lambda: (s := _stream(c, "case-1", "sonar")) and s.get("count") == 3 and s, 15, what="sonar"
            )
            assert (sonar["gaps_open"], sonar["gaps_lost"]) == (0, 0)
        assert len(robot.requests()) == 1
        assert [seq for seq, _ in _stored_rows(database_url, "case-1")] == list(range(30))
    finally:
        robot.close()
