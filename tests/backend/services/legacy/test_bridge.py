"""Robots running the original Mollusca MQTT module appear in the fleet, marked legacy."""

from __future__ import annotations

import time

import orjson

from fleet_protocol import (
    LEGACY_APRILTAG_TOPIC,
    LEGACY_COMMAND_TOPIC,
    LEGACY_IMU_TOPIC,
    LEGACY_POSITION_TOPIC,
    SEED_COMMANDS,
    legacy_namespaced_command_topic,
)
from tests.backend.helpers import register_legacy, wait_robot
from tests.support.procs import ServerProcess, wait_for


def _pub(probe, topic: str, obj: object) -> None:
    probe.publish(topic, orjson.dumps(obj), qos=0)


def test_legacy_position_shapes_stored_and_bad_ones_counted(server, mqtt_probe):
    probe = mqtt_probe()
    with server.client() as c:
        register_legacy(c, "snail1")
    shapes = ["1.0,2.0,3.0", "[1.5, 2.5, 3.5]", "2 3 4", [3, 4, 5], {"x": 4, "y": 5, "z": 6}]
    for shape in shapes:
        _pub(probe, LEGACY_POSITION_TOPIC, {"robot_id": "snail1", "position": shape})
    _pub(probe, LEGACY_POSITION_TOPIC, {"robot_id": "snail1", "position": "somewhere over there"})
    _pub(probe, LEGACY_POSITION_TOPIC, {"robot_id": "snail1"})
    with server.client() as c:
        robot = wait_robot(c, "snail1", lambda r: r["position"] is not None and r["position"]["x"] == 4)
        assert robot["legacy"] is True and robot["online"] is True
        assert robot["capabilities"]["commands"] == list(SEED_COMMANDS)
        assert robot["capabilities"]["sensors"] == ["position"]
        pts = wait_for(lambda: len(p := c.get("/api/robots/snail1/telemetry").json()["points"]) == 5 and p, 5)
        assert [(p["data"]["x"], p["data"]["y"], p["data"]["z"]) for p in pts] == [
            (1.0, 2.0, 3.0),
            (1.5, 2.5, 3.5),
            (2.0, 3.0, 4.0),
            (3.0, 4.0, 5.0),
            (4.0, 5.0, 6.0),
        ]
        assert [p["seq"] for p in pts] == [0, 1, 2, 3, 4]
        rejects = c.get("/api/health").json()["rejects"]
        assert rejects["by_kind"]["legacy"] == 2
        assert rejects["by_reason"]["bad_legacy"] == 1


def test_legacy_imu_mapped_to_fleet_schema_or_kept_verbatim(server, mqtt_probe):
    probe = mqtt_probe()
    with server.client() as c:
        register_legacy(c, "snail2")
    _pub(
        probe,
        LEGACY_IMU_TOPIC,
        {"robot_id": "snail2", "imu_data": {"accel": [0, 0, 9.8], "gyro": [0, 0, 0.1]}},
    )
    _pub(probe, LEGACY_IMU_TOPIC, {"robot_id": "snail2", "imu_data": {"ax": 1}})
    with server.client() as c:
        imu = wait_for(lambda: c.get("/api/robots/snail2/telemetry", params={"stream": "imu"}).json()["points"], 5)
        assert imu[0]["data"] == {"accel": [0.0, 0.0, 9.8], "gyro": [0.0, 0.0, 0.1]}
        raw = wait_for(
            lambda: c.get("/api/robots/snail2/telemetry", params={"stream": "legacy_imu"}).json()["points"], 5
        )
        assert raw[0]["data"] == {"value": {"ax": 1}}
        # the seed's AprilTag detections (a list of dicts) are kept verbatim
        seed_tags = [{"tag_id": 3, "translation": [10.0, 0.0, 500.0], "euler": [0.0, 1.0, 2.0]}]
        _pub(probe, LEGACY_APRILTAG_TOPIC, {"robot_id": "snail2", "apriltag_data": seed_tags})
        tags = wait_for(
            lambda: c.get("/api/robots/snail2/telemetry", params={"stream": "legacy_apriltag"}).json()["points"],
            5,
        )
        assert tags[0]["data"] == {"value": seed_tags}
        robot = c.get("/api/robots/snail2").json()
        assert robot["legacy"] and sorted(robot["capabilities"]["sensors"]) == [
            "imu",
            "legacy_apriltag",
            "legacy_imu",
        ]


def test_legacy_commands_are_plain_strings_acked_by_server(server, mqtt_probe):
    listener = mqtt_probe(LEGACY_COMMAND_TOPIC, legacy_namespaced_command_topic("snail3"))
    with server.client() as c:
        register_legacy(c, "snail3")
    _pub(mqtt_probe(), LEGACY_POSITION_TOPIC, {"robot_id": "snail3", "position": "0,0,0"})
    with server.client() as c:
        wait_robot(c, "snail3", lambda r: r["online"])
        t0 = time.monotonic()
        r = c.post("/api/robots/snail3/commands?wait=5", json={"command": "move_forward"})
        assert time.monotonic() - t0 < 2  # no robot ack to wait for
        assert r.status_code == 200, r.text
        assert r.json()["status"] == "accepted" and r.json()["reason"] == "legacy robot: no ack"
        # the seed's code listens on the shared topic: the drive goes there only (the robot's own topic
        # is for robots changed to listen on it; tests/backend/services/legacy/test_relay.py)
        msg = listener.wait(lambda m: m.topic == LEGACY_COMMAND_TOPIC)
        assert msg.payload == b"move_forward"
        listener.wait(lambda m: m.topic == LEGACY_COMMAND_TOPIC and m.payload == b"stop")  # its deadman lapsed
        assert [m.topic for m in listener.matching(lambda m: m.payload == b"move_forward")] == [LEGACY_COMMAND_TOPIC]
        r = c.post("/api/robots/snail3/commands", json={"command": "set_speed"})
        assert r.status_code == 422


def test_legacy_robot_offline_after_silence(broker, database_url, workdir, mqtt_probe):
    s = ServerProcess(broker, database_url, workdir, FLEET_LEGACY_OFFLINE_AFTER_S="1")
    s.start()
    try:
        with s.client() as c:
            register_legacy(c, "snail4")
            _pub(mqtt_probe(), LEGACY_POSITION_TOPIC, {"robot_id": "snail4", "position": "1,1,0"})
            wait_robot(c, "snail4", lambda r: r["online"])
            wait_robot(c, "snail4", lambda r: not r["online"], timeout=5)
            assert c.post("/api/robots/snail4/commands", json={"command": "stop"}).status_code == 409
    finally:
        s.stop()
