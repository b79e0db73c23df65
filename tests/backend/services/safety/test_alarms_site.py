"""The site's alarm rules against a real server, broker and database: ``geofence_breach`` from the robots'
own geofence reports, and ``localization_disagreement`` from real simulated agents whose camera sees the
site's wall tags, one of them with its Lighthouse off by 20 cm."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from robot_agent.sim.world import default_tags
from tests.backend.helpers import ProbeRobot, wait_robot
from tests.support.procs import ServerProcess, wait_for


def _open(c: Any, robot_id: str) -> dict[str, dict[str, Any]]:
    return {a["kind"]: a for a in c.get("/api/alarms", params={"state": "open"}).json() if a["robot_id"] == robot_id}


def _geofence(robot: ProbeRobot, seq: int, event: str, x: float, y: float, reason: str = "") -> None:
    robot.telemetry(seq, {"event": event, "command_id": None, "x": x, "y": y, "reason": reason}, stream="geofence")


def test_geofence_breach_raised_by_outside_cleared_by_inside(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "gf-1", sensors=("position", "geofence"))
    robot.status()
    with server.client() as c:
        wait_robot(c, "gf-1", lambda r: r["online"])
        # the fence working (a motion stopped or refused at it) is no breach; the later "outside" is, and the
        # alarm it raises carries its own position: had "stopped" or "refused" raised it, theirs would be there
        _geofence(robot, 0, "stopped", 1.81, 0.0, "goal would cross the fence")
        _geofence(robot, 1, "refused", 1.82, 0.0, "drive would cross the fence")
        _geofence(robot, 2, "outside", 2.07, -0.5, "idle: drifting with the water")
        alarm = wait_for(lambda: _open(c, "gf-1").get("geofence_breach"), 2, what="geofence_breach")
        assert alarm["severity"] == "warning" and alarm["state"] == "active"
        assert alarm["detail"]["x"] == 2.07 and "(2.07, -0.50)" in alarm["message"]
        assert "drifting" in alarm["message"]
        assert c.get("/api/robots/gf-1").json()["alarms"] == {"geofence_breach": "warning"}

        _geofence(robot, 3, "inside", 1.5, -0.5)
        wait_for(lambda: "geofence_breach" not in _open(c, "gf-1"), 2, what="cleared when back inside")
        history = [a for a in c.get("/api/alarms").json() if a["robot_id"] == "gf-1"]
        assert [(t["state"], t["by"]) for t in history[0]["transitions"]] == [
            ("active", "system"),
            ("cleared", "system"),
        ]

        # an admin can turn the rule off: the next breach raises nothing (the rule list says so)
        r = c.put("/api/alarm-rules", json={"kind": "geofence_breach", "enabled": False})
        assert r.status_code == 200 and {x["kind"]: x for x in r.json()}["geofence_breach"]["enabled"] is False
        assert c.put("/api/alarm-rules", json={"kind": "geofence_breach", "params": {"above_m": 1}}).status_code == 422
        _geofence(robot, 4, "outside", 2.1, 0.0)
        _geofence(robot, 5, "bogus", 2.1, 0.0)  # not a geofence event: refused at the door, nothing else happens
        robot.telemetry(0, {"x": 2.1, "y": 0.0, "z": 0.0})
        wait_for(lambda: c.get("/api/robots/gf-1").json()["position"] is not None, 3, what="a later message")
        assert "geofence_breach" not in _open(c, "gf-1")


SITE_TAGS = [
    {"id": t.id, "size_m": t.size_m, "pose": {"x": t.x, "y": t.y, "z": t.z, "yaw": t.yaw}} for t in default_tags()
]


def test_localization_disagreement_from_real_agents(broker, database_url, workdir: Path, spawn_agent):
    """Two simulated agents with cameras facing the east wall's tag 0: one's Lighthouse is true, the other's
    is 20 cm off. Only the second raises the alarm, though both have frames compared; a threshold over its
    error clears it."""
    offset = workdir / "offset.toml"
    offset.write_text("[sim]\nlighthouse_offset_m = [0.2, 0.0]\n")
    server = ServerProcess(broker, database_url, workdir, FLEET_SITE_TAGS=json.dumps(SITE_TAGS))
    server.start()
    try:
        spawn_agent("loc-true", "--camera", "--start-pose=1,0.3,0")
        spawn_agent("loc-off", "--camera", "--start-pose=1,-0.3,0", "--config", str(offset))
        with server.client() as c:
            for rid in ("loc-true", "loc-off"):
                wait_robot(c, rid, lambda r: r["online"] and r["position"] is not None, timeout=30)
            alarm = wait_for(
                lambda: _open(c, "loc-off").get("localization_disagreement"), 30, what="localization_disagreement"
            )
            assert alarm["severity"] == "warning"
            assert 0.17 <= alarm["detail"]["apart_m"] <= 0.23, alarm
            tag_x, tag_y = alarm["detail"]["tag_xy"]
            assert abs(tag_x - 1.0) < 0.05 and abs(tag_y + 0.3) < 0.05  # the tags see the true pose
            assert abs(alarm["detail"]["lighthouse_xy"][0] - 1.2) < 0.05

            # the true robot's frames were compared all along (it sees tag 0 too), and agree
            def tags_seen() -> int:
                points = c.get("/api/robots/loc-true/telemetry", params={"stream": "apriltag", "raw": "true"}).json()
                return sum(1 for p in points["points"] if any(d["tag_id"] == 0 for d in p["data"]["detections"]))

            assert wait_for(lambda: tags_seen() >= 10, 10, what="tag 0 in the true robot's frames")
            assert "localization_disagreement" not in _open(c, "loc-true")

            # a threshold over the 20 cm error: the alarm clears on the next frames
            r = c.put("/api/alarm-rules", json={"kind": "localization_disagreement", "params": {"above_m": 0.3}})
            assert r.status_code == 200, r.text
            wait_for(lambda: "localization_disagreement" not in _open(c, "loc-off"), 10, what="cleared")
            audit = c.get("/api/audit", params={"action": "alarm_rule"}).json()
            assert audit[0]["detail"]["kind"] == "localization_disagreement"
    finally:
        server.stop()
