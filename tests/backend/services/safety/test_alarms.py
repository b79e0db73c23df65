"""Alarms and readiness against a real server, broker and database, robots simulated at the MQTT level."""

from __future__ import annotations

import time
from typing import Any

from tests.backend.helpers import ProbeRobot, wait_robot
from tests.support.procs import wait_for


def _open(c: Any, robot_id: str) -> dict[str, dict[str, Any]]:
    return {a["kind"]: a for a in c.get("/api/alarms", params={"state": "open"}).json() if a["robot_id"] == robot_id}


def _health(robot: ProbeRobot, seq: int, **fields: Any) -> None:
    robot.telemetry(seq, {"battery_pct": None, "cpu_temp_c": None, **fields}, stream="health")


def test_battery_critical_stops_refuses_is_acknowledged_and_clears(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "bat-1", sensors=("position", "health"))
    robot.status()
    robot.telemetry(0, {"x": 0.0, "y": 0.0, "z": 0.0})
    with server.client() as c:
        wait_robot(c, "bat-1", lambda r: r["online"])
        _health(robot, 0, battery_pct=55.0)
        wait_for(lambda: c.get("/api/robots/bat-1").json()["position"] is not None, 5, what="position")
        assert _open(c, "bat-1") == {}  # a healthy battery raises nothing: the check below can tell
        assert c.post("/api/robots/bat-1/commands", json={"command": "move_forward"}).status_code == 202

        low_at = time.time()
        _health(robot, 1, battery_pct=4.0)
        alarms = wait_for(
            lambda: {"battery_critical", "battery_low"} <= (a := _open(c, "bat-1")).keys() and a,
            2,
            what="both battery alarms (below both thresholds)",
        )
        assert time.time() - low_at <= 2.0
        critical = alarms["battery_critical"]
        assert critical["severity"] == "critical" and critical["state"] == "active"
        # it is stopped, and its drives are refused (stop passes)
        stop = robot.probe.wait(lambda m: m.topic.endswith("/cmd") and b'"stop"' in m.payload, 5)
        assert stop is not None
        refused = c.post("/api/robots/bat-1/commands", json={"command": "move_forward"})
        assert refused.status_code == 409 and refused.json()["code"] == "battery_critical", refused.text
        assert c.post("/api/robots/bat-1/commands", json={"command": "stop"}).status_code == 202
        r = c.get("/api/robots/bat-1").json()
        assert r["ready"] is False and "battery below the threshold" in r["not_ready_reasons"]
        assert r["alarms"]["battery_critical"] == "critical"
        assert 'fleet_alarms_active{severity="critical"} 1.0' in c.get("/metrics").text

        # acknowledged: stored with who
        acked = c.post(f"/api/alarms/{critical['id']}/ack")
        assert acked.status_code == 200 and acked.json()["state"] == "acknowledged", acked.text
        assert acked.json()["acked_by"] == "FLEET_ADMIN_TOKEN"
        assert c.post("/api/alarms/999999/ack").status_code == 404
        assert c.post("/api/robots/bat-1/commands", json={"command": "move_forward"}).status_code == 409

        # back above the threshold: cleared, and it drives again
        _health(robot, 2, battery_pct=80.0)
        wait_for(lambda: _open(c, "bat-1") == {}, 3, what="alarms cleared")
        assert c.post("/api/robots/bat-1/commands", json={"command": "move_forward"}).status_code == 202
        history = {a["kind"]: a for a in c.get("/api/alarms").json() if a["robot_id"] == "bat-1"}
        steps = [(t["state"], t["by"]) for t in history["battery_critical"]["transitions"]]
        assert steps == [("active", "system"), ("acknowledged", "FLEET_ADMIN_TOKEN"), ("cleared", "system")]
        audit = c.get("/api/audit", params={"action": "alarm_ack"}).json()
        assert audit[0]["robot_id"] == "bat-1" and audit[0]["detail"]["kind"] == "battery_critical"


def test_an_admin_overrides_a_critical_battery_and_rules_can_be_changed(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "bat-2", sensors=("position", "health"))
    robot.status()
    with server.client() as c:
        wait_robot(c, "bat-2", lambda r: r["online"])
        assert c.post("/api/robots/bat-2/battery-override").status_code == 409  # nothing to override yet
        _health(robot, 0, battery_pct=5.0)
        wait_for(lambda: "battery_critical" in _open(c, "bat-2"), 3, what="battery alarm")
        assert c.post("/api/robots/bat-2/commands", json={"command": "move_forward"}).status_code == 409
        assert c.post("/api/robots/bat-2/battery-override").status_code == 200
        assert c.post("/api/robots/bat-2/commands", json={"command": "move_forward"}).status_code == 202
        assert c.get("/api/audit", params={"action": "battery_override"}).json()[0]["robot_id"] == "bat-2"

        # thresholds: only the rule's own parameters; an unknown rule or parameter is a 422
        r = c.put("/api/alarm-rules", json={"kind": "cpu_hot", "params": {"above_c": 50}})
        assert r.status_code == 200 and {x["kind"]: x for x in r.json()}["cpu_hot"]["params"] == {"above_c": 50.0}
        assert c.put("/api/alarm-rules", json={"kind": "nope"}).status_code == 422
        assert c.put("/api/alarm-rules", json={"kind": "cpu_hot", "params": {"below": 1}}).status_code == 422
        assert c.put("/api/alarm-rules", json={"kind": "cpu_hot", "params": {"above_c": True}}).status_code == 422
        _health(robot, 1, battery_pct=90.0, cpu_temp_c=60.0)
        wait_for(lambda: "cpu_hot" in _open(c, "bat-2"), 3, what="cpu_hot at the admin's threshold")


def test_data_lost_for_good_raises_data_gap_and_clears_once_acknowledged(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "gap-1")
    robot.status()
    with server.client() as c:
        wait_robot(c, "gap-1", lambda r: r["online"])
        for seq in (0, 1, 2):
            robot.telemetry(seq, {"x": 0.0, "y": 0.0, "z": 0.0})
        wait_for(lambda: c.get("/api/robots/gap-1/streams").json(), 5, what="stream stored")
        assert "data_gap" not in _open(c, "gap-1")  # an unbroken stream raises nothing
        robot.telemetry(10, {"x": 0.0, "y": 0.0, "z": 0.0})  # 3..9 missing, and no boot id: lost for good
        gap = wait_for(lambda: _open(c, "gap-1").get("data_gap"), 5, what="data_gap alarm")
        assert gap["detail"]["lost"] == 7 and gap["detail"]["stream"] == "position"
        assert c.post(f"/api/alarms/{gap['id']}/ack").status_code == 200
        wait_for(lambda: "data_gap" not in _open(c, "gap-1"), 3, what="an acknowledged loss is over")


def test_prometheus_alert_rules_use_exported_metrics_and_the_same_thresholds(server, mqtt_probe):
    import re
    from pathlib import Path

    import yaml

    from backend.core.alarm_rules import RULES

    rules = yaml.safe_load((Path(__file__).resolve().parents[4] / "deploy/prometheus/alerts.yml").read_text())
    alerts = {r["alert"]: r["expr"] for g in rules["groups"] for r in g["rules"]}
    robot = ProbeRobot(mqtt_probe, "prom-1", sensors=("position", "health"))
    robot.status()
    robot.telemetry(0, {"x": 0.0, "y": 0.0, "z": 0.0})
    robot.telemetry(
        0,
        {"battery_pct": 50.0, "cpu_temp_c": 40.0, "wifi_rssi_dbm": -50.0, "clock_offset_ms": 1.0, "motor_fault": False},
        stream="health",
    )
    with server.client() as c:
        wait_for(lambda: "fleet_robot_battery_pct{" in c.get("/metrics").text, 5, what="health gauges")
        exported = set(re.findall(r"^# TYPE (\w+) ", c.get("/metrics").text, flags=re.M))
    for name, expr in alerts.items():
        for metric in re.findall(r"\bfleet_\w+", expr):
            assert metric in exported, (name, metric)
    assert f"< {RULES['battery_low'].params['below_pct']:g}" in alerts["BatteryLow"]
    assert f"< {RULES['battery_critical'].params['below_pct']:g}" in alerts["BatteryCritical"]
    assert f"> {RULES['cpu_hot'].params['above_c']:g}" in alerts["CpuHot"]
    assert f"< {RULES['wifi_weak'].params['below_dbm']:g}" in alerts["WifiWeak"]
    assert f"> {RULES['clock_offset'].params['above_ms']:g}" in alerts["ClockOffset"]
