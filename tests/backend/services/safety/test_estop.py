"""Fleet e-stop: retained on the broker, acks collected per robot, release."""

from __future__ import annotations

import orjson
import pytest

from tests.backend.helpers import TOPICS, ProbeRobot, wait_robot
from tests.support.procs import wait_for

pytestmark = pytest.mark.realtime  # wall-clock safety bounds: the realtime lane, alone (docs/testing.md)


def test_estop_retained_acked_and_released(server, mqtt_probe):
    r1 = ProbeRobot(mqtt_probe, "r1")
    r2 = ProbeRobot(mqtt_probe, "r2")
    r1.status()
    r2.status()
    with server.client() as c:
        wait_robot(c, "r2", lambda r: r["online"])
        r = c.post("/api/estop", json={"reason": "test"})
        assert r.status_code == 202
        body = r.json()
        assert body["engaged"] is True and body["robots"] == ["r1", "r2"]
        for robot in (r1, r2):
            msg = orjson.loads(robot.wait_estop(True).payload)
            assert msg["id"] == body["id"] and msg["reason"] == "test"
        # retained: a robot connecting later still sees it
        late = mqtt_probe(TOPICS.estop())
        retained = late.wait(lambda m: m.topic == TOPICS.estop())
        assert retained.retain and orjson.loads(retained.payload)["engaged"] is True
        r1.ack(body["id"], "done", "stopped")
        r2.ack(body["id"], "accepted")
        state = wait_for(
            lambda: (s := c.get("/api/estop").json())["acks"] == {"r1": "done", "r2": "accepted"} and s,
            5,
            what="estop acks",
        )
        assert state["engaged"] is True and state["id"] == body["id"] and state["reason"] == "test"
        # e-stop acks are not command acks
        assert c.get("/api/health").json()["rejects"]["total"] == 0
        rel = c.post("/api/estop/release")
        assert rel.status_code == 202 and rel.json()["engaged"] is False
        r1.wait_estop(False)
        assert c.get("/api/estop").json()["engaged"] is False
    late2 = mqtt_probe(TOPICS.estop())
    retained = late2.wait(lambda m: m.topic == TOPICS.estop())
    assert retained.retain and orjson.loads(retained.payload)["engaged"] is False


def test_estop_state_restored_from_retained_message(broker, database_url, workdir, mqtt_probe):
    """The e-stop state follows the retained topic, so a (re)started server knows it is engaged."""
    from fleet_protocol import EStop, dumps
    from tests.support.procs import ServerProcess

    probe = mqtt_probe()
    probe.publish(TOPICS.estop(), dumps(EStop(ts=1.0, id="e-1", engaged=True, reason="earlier")), retain=True)
    s = ServerProcess(broker, database_url, workdir)
    s.start()
    try:
        with s.client() as c:
            state = wait_for(lambda: (x := c.get("/api/estop").json())["engaged"] and x, 5, what="estop restored")
            assert state["id"] == "e-1" and state["reason"] == "earlier"
    finally:
        s.stop()


def test_events_recorded(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "r1")
    robot.status()
    with server.client() as c:
        wait_robot(c, "r1", lambda r: r["online"])
        estop_id = c.post("/api/estop").json()["id"]
        robot.ack(estop_id, "done")
        robot.status(online=False)
        robot.probe.publish(TOPICS.status("r1"), b"garbage")

        def kinds():
            ev = c.get("/api/events").json()
            k = [e["kind"] for e in ev]
            return ev if {"online", "offline", "estop", "estop_ack", "reject"} <= set(k) else None

        events = wait_for(kinds, 5, what="events")
        assert [e["ts"] for e in events] == sorted((e["ts"] for e in events), reverse=True)
        ack = next(e for e in events if e["kind"] == "estop_ack")
        assert ack["robot_id"] == "r1" and ack["detail"]["id"] == estop_id
        rej = next(e for e in events if e["kind"] == "reject")
        assert rej["detail"]["reason"] == "bad_json" and rej["detail"]["kind"] == "status"
        only = c.get("/api/events", params={"kind": "offline", "robot_id": "r1"}).json()
        assert len(only) == 1 and only[0]["detail"]["source"] == "status"
        assert c.get("/api/events", params={"start": "bad"}).status_code == 422


def test_sensor_failures_and_recoveries_are_events(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "r2", sensors=("position", "camera"))
    robot.status(sensors={"camera": {"ok": True}})
    with server.client() as c:
        wait_robot(c, "r2", lambda r: r["online"])
        robot.status(sensors={"camera": {"ok": False, "error": "no camera at /dev/video0"}})
        robot.status(sensors={"camera": {"ok": False, "error": "no camera at /dev/video0"}})  # unchanged: no event
        robot.status(sensors={"camera": {"ok": True}})

        def events():
            ev = c.get("/api/events", params={"robot_id": "r2"}).json()
            kinds = [e["kind"] for e in ev]
            return ev if "sensor_recovered" in kinds else None

        ev = wait_for(events, 5, what="sensor events")
        sensor = [e for e in ev if e["kind"].startswith("sensor_")]
        assert [e["kind"] for e in reversed(sensor)] == ["sensor_failed", "sensor_recovered"]
        assert sensor[-1]["detail"] == {"sensor": "camera", "error": "no camera at /dev/video0"}
