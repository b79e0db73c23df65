"""Oversize MQTT messages through a real broker: the server refuses them (counted by reason, dropped),
keeps the robot's last good value, and goes on with the next good message."""

from __future__ import annotations

from fleet_protocol import MAX_JSON_PAYLOAD_BYTES, encode_telemetry
from tests.backend.helpers import TOPICS, ProbeRobot, wait_robot
from tests.support.procs import wait_for


def test_oversize_telemetry_refused_and_last_value_kept(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "r1")
    robot.status()
    robot.telemetry(1, {"x": 1.0, "y": 2.0})
    with server.client() as c:
        wait_robot(c, "r1", lambda r: r["position"] is not None and r["position"]["x"] == 1.0)
        big = encode_telemetry(2, {"x": 9.0, "y": 9.0, "pad": "x" * MAX_JSON_PAYLOAD_BYTES})
        robot.probe.publish(TOPICS.telemetry("r1", "position"), big)
        robot.probe.publish(TOPICS.status("r1"), b'{"online": true, "pad": "' + b"x" * MAX_JSON_PAYLOAD_BYTES + b'"}')
        wait_for(
            lambda: c.get("/api/stats").json()["rejects"]["by_reason"].get("oversize", 0) == 2,
            10,
            what="oversize rejects",
        )
        robot.telemetry(3, {"x": 3.0, "y": 2.0})
        got = wait_robot(c, "r1", lambda r: r["position"]["x"] == 3.0)
        assert got["online"] is True  # the oversize status was not applied

        def stored() -> list[int]:
            points = c.get("/api/robots/r1/telemetry", params={"stream": "position"}).json()["points"]
            return [p["seq"] for p in points]

        wait_for(lambda: 3 in stored(), 10, what="seq 3 stored")
        assert stored() == [1, 3]  # the oversize message was never stored
