"""Malformed input on every subscribed topic kind is counted, logged and dropped; the bridge keeps going."""

from __future__ import annotations

import time

import orjson

from fleet_protocol import LEGACY_POSITION_TOPIC
from tests.backend.helpers import TOPICS, ProbeRobot, wait_robot
from tests.support.procs import wait_for

BAD = [
    # (topic, payload, expected reason)
    (TOPICS.status("r1"), b"{not json", "bad_json"),
    (TOPICS.status("r1"), b"[1, 2]", "bad_status"),
    (TOPICS.status("r1"), orjson.dumps({"online": "maybe", "ts": 1.0}), "bad_status"),
    (TOPICS.telemetry("r1", "position"), b"\xff\xfe", "bad_json"),
    (
        TOPICS.telemetry("r1", "position"),
        orjson.dumps({"ts": 1.0, "data": {"x": 1, "y": 2}}),
        "bad_telemetry",
    ),
    (
        TOPICS.telemetry("r1", "position"),
        orjson.dumps({"ts": 1.0, "seq": 0, "data": {"x": "a"}}),
        "bad_position",
    ),
    (TOPICS.telemetry("r1", "position"), b'{"ts": NaN, "seq": 0, "data": {}}', "bad_json"),
    (TOPICS.telemetry("r1", "position"), b" " * (300 * 1024), "oversize"),
    ("fleet/r1/telemetry/bad$stream", orjson.dumps({"ts": 1.0, "seq": 0, "data": {}}), "bad_stream"),
    ("fleet/bad$robot/status", orjson.dumps({"online": True, "ts": 1.0}), "bad_robot_id"),
    (
        "fleet/" + "x" * 65 + "/telemetry/position",
        orjson.dumps({"ts": 1.0, "seq": 0, "data": {}}),
        "bad_robot_id",
    ),
    (TOPICS.ack("r1"), orjson.dumps({"id": "c1", "status": "sideways", "ts": 1.0}), "bad_ack"),
    (TOPICS.ack("r1"), b"", "bad_json"),
    (TOPICS.estop(), b"{]", "bad_json"),
    (TOPICS.estop(), orjson.dumps({"engaged": "yes"}), "bad_estop"),
    (LEGACY_POSITION_TOPIC, orjson.dumps({"robot_id": "bad id!", "position": "1,2,3"}), "bad_robot_id"),
    (LEGACY_POSITION_TOPIC, b"nope", "bad_json"),
]


def test_malformed_payloads_counted_and_dropped(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "r1")
    robot.status()
    with server.client() as c:
        wait_robot(c, "r1", lambda r: r["online"])
        before = c.get("/api/health").json()["rejects"]["total"]
        assert before == 0
        for topic, payload, _ in BAD:
            robot.probe.publish(topic, payload)
        expected: dict[str, int] = {}
        for _, _, reason in BAD:
            expected[reason] = expected.get(reason, 0) + 1
        health = wait_for(
            lambda: (h := c.get("/api/health").json())["rejects"]["total"] >= len(BAD) and h,
            10,
            what="all rejects counted",
        )
        assert health["rejects"]["total"] == len(BAD)
        for reason, n in expected.items():
            assert health["rejects"]["by_reason"].get(reason) == n, (reason, health["rejects"])
        assert set(health["rejects"]["by_kind"]) >= {"status", "telemetry", "ack", "estop", "legacy"}
        assert health["status"] == "ok" and health["mqtt"]["connected"] is True
        # state was not damaged: robot still online, e-stop not engaged, no bogus robots
        assert c.get("/api/robots/r1").json()["online"] is True
        assert c.get("/api/estop").json()["engaged"] is False
        assert [r["id"] for r in c.get("/api/robots").json()] == ["r1"]
        # and a good message still gets through
        robot.telemetry(0, {"x": 1.5, "y": 2.5, "z": 0.0}, ts=time.time())
        wait_for(lambda: c.get("/api/robots/r1/telemetry").json()["points"], 5, what="good telemetry")
    log = server.output()
    assert "rejected telemetry message" in log
    # rate-limited: two bad_json telemetry rejects produce one warning line
    assert log.count("rejected telemetry message on 'fleet/r1/telemetry/position': bad_json") == 1
