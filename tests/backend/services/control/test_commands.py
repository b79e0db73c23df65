"""REST commands against a robot played by an MQTT probe: validation, publish, acks, ?wait."""

from __future__ import annotations

import threading
import time
import uuid

import orjson
import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from tests.backend.helpers import TOPICS, ProbeRobot, wait_robot
from tests.support.procs import wait_for


def _online_robot(mqtt_probe, server, robot_id="r1", **kw) -> ProbeRobot:
    robot = ProbeRobot(mqtt_probe, robot_id, **kw)
    robot.status(online=True)
    with server.client() as c:
        wait_robot(c, robot_id, lambda r: r["online"])
    return robot


def test_command_reaches_robot_and_acks_update_record(server, mqtt_probe):
    robot = _online_robot(mqtt_probe, server)
    with server.client() as c:
        r = c.post("/api/robots/r1/commands", json={"command": "move_forward", "args": {"speed": 0.4}})
        assert r.status_code == 202, r.text
        cmd = r.json()
        assert cmd["status"] == "sent" and cmd["robot_id"] == "r1" and cmd["source"] == "rest"
        wire = robot.next_command()
        assert wire["id"] == cmd["id"] and wire["command"] == "move_forward"
        assert wire["args"] == {"speed": 0.4, "duration_s": 0.5}  # validated, defaults made explicit
        assert wire["ttl_s"] == cmd["ttl_s"] == 2.0
        robot.ack(cmd["id"], "accepted")
        robot.ack(cmd["id"], "done", "finished")
        got = wait_for(
            lambda: (x := c.get(f"/api/commands/{cmd['id']}").json())["status"] == "done" and x,
            5,
            what="done status",
        )
        assert [a["status"] for a in got["acks"]] == ["accepted", "done"]
        assert got["reason"] == "finished"

        # stored: the robot's history (newest first) has it with both acks
        def stored():
            hist = c.get("/api/robots/r1/commands").json()
            return hist if hist and len(hist[0]["acks"]) == 2 else None

        hist = wait_for(stored, 5, what="command history")
        assert hist[0]["id"] == cmd["id"]


def test_wait_returns_final_ack(server, mqtt_probe):
    robot = _online_robot(mqtt_probe, server)

    def play() -> None:
        cmd = robot.next_command()
        robot.ack(cmd["id"], "accepted")
        # the server has the non-final ack while ?wait is still waiting: it must go on waiting for "done"
        with server.client() as watcher:
            wait_for(lambda: watcher.get(f"/api/commands/{cmd['id']}").json()["status"] == "accepted", 5)
        robot.ack(cmd["id"], "done")

    t = threading.Thread(target=play)
    t.start()
    with server.client() as c:
        r = c.post("/api/robots/r1/commands?wait=5", json={"command": "turn_left", "args": {"duration_s": 0.2}})
    t.join()
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["status"] == "done"
    assert [a["status"] for a in body["acks"]] == ["accepted", "done"]
    assert all(a["received_ts"] >= body["ts"] for a in body["acks"])


def test_wait_returns_latest_non_final_ack(server, mqtt_probe):
    robot = _online_robot(mqtt_probe, server)

    def play() -> None:
        robot.ack(robot.next_command()["id"], "accepted")

    t = threading.Thread(target=play)
    t.start()
    with server.client() as c:
        r = c.post("/api/robots/r1/commands?wait=1", json={"command": "stop"})
    t.join()
    assert r.status_code == 200 and r.json()["status"] == "accepted"


def test_wait_without_ack_is_504_timeout(server, mqtt_probe):
    robot = _online_robot(mqtt_probe, server)
    with server.client() as c:
        t0 = time.monotonic()
        r = c.post("/api/robots/r1/commands?wait=0.5", json={"command": "stop"})
        assert time.monotonic() - t0 >= 0.5
        assert r.status_code == 504
        assert r.json()["status"] == "timeout"
        assert robot.next_command()["id"] == r.json()["id"]  # it was still sent
        assert c.get(f"/api/commands/{r.json()['id']}").json()["status"] == "timeout"
        # a late ack still counts
        robot.ack(r.json()["id"], "done")
        wait_for(lambda: c.get(f"/api/commands/{r.json()['id']}").json()["status"] == "done", 5)


def test_rejected_ack_reason(server, mqtt_probe):
    robot = _online_robot(mqtt_probe, server)

    def play() -> None:
        robot.ack(robot.next_command()["id"], "rejected", "motor not operable")

    t = threading.Thread(target=play)
    t.start()
    with server.client() as c:
        r = c.post("/api/robots/r1/commands?wait=5", json={"command": "move_backward"})
    t.join()
    assert r.status_code == 200
    assert r.json()["status"] == "rejected" and r.json()["reason"] == "motor not operable"


def test_error_paths(server, mqtt_probe):
    robot = _online_robot(mqtt_probe, server, commands=["move_forward", "stop"])
    with server.client() as c:
        r = c.post("/api/robots/nobody/commands", json={"command": "stop"})
        assert r.status_code == 404 and "nobody" in r.json()["detail"]
        r = c.post("/api/robots/r1/commands", json={"command": "turn_left"})
        assert r.status_code == 422 and "not supported" in r.json()["detail"]
        r = c.post("/api/robots/r1/commands", json={"command": "move_forward", "args": {"speed": 3}})
        assert r.status_code == 422 and "speed" in r.json()["detail"]
        r = c.post("/api/robots/r1/commands", json={"command": "move_forward", "args": {"duration_s": 60}})
        assert r.status_code == 422 and "duration_s" in r.json()["detail"]
        r = c.post("/api/robots/r1/commands", json={"command": "move_forward", "args": {"warp": 9}})
        assert r.status_code == 422 and "warp" in r.json()["detail"]
        # booleans are not numbers: lax parsing would drive at full speed (true -> 1.0) or for 1 s
        not_numbers: list[dict] = [
            {"args": {"speed": True}},
            {"args": {"duration_s": True}},
            {"ttl_s": True},
            {"args": {"speed": "0.5"}},
        ]
        for bad in not_numbers:
            r = c.post("/api/robots/r1/commands", json={"command": "move_forward", **bad})
            assert r.status_code == 422, (bad, r.text)
        r = c.post("/api/robots/r1/commands", json={"command": "move_forward", "args": {"speed": 0, "duration_s": 1}})
        assert r.status_code == 202  # an integer is a number
        commands_sent = 1
        r = c.post("/api/robots/r1/commands", json={"command": "stop", "args": {"speed": 1}})
        assert r.status_code == 422
        r = c.post("/api/robots/r1/commands", json={"command": "Bad Name!"})
        assert r.status_code == 422
        r = c.post("/api/robots/r1/commands?wait=11", json={"command": "stop"})
        assert r.status_code == 422
        r = c.post("/api/robots/r1/commands", content=b"{not json", headers={"content-type": "application/json"})
        assert r.status_code == 422
        assert c.get("/api/commands/does-not-exist").status_code == 404
        assert c.get("/api/robots/nobody/commands").status_code == 404
        # nothing invalid reached the robot: a valid command sent after them arrives, and it arrives
        # second (commands go out in order on one topic, so an invalid one published would come first)
        assert c.post("/api/robots/r1/commands", json={"command": "stop"}).status_code == 202
        commands_sent += 1
        wait_for(lambda: any(m["command"] == "stop" for m in robot.commands_received()), 5, what="the stop")
        received = robot.commands_received()
        assert len(received) == commands_sent and received[0]["args"] == {"speed": 0.0, "duration_s": 1.0}
        robot.status(online=False)
        wait_robot(c, "r1", lambda x: not x["online"])
        r = c.post("/api/robots/r1/commands", json={"command": "stop"})
        assert r.status_code == 409 and "offline" in r.json()["detail"]


def test_last_will_marks_robot_offline(server, mqtt_probe):
    """A robot whose connection dies is marked offline by its Last Will. When is the broker's business:
    Mosquitto 2.0 sweeps keepalives every few seconds, so the will fires 1.5 s (1.5 x keepalive 1 s) to
    ~6.5 s after the last packet. (Agents also announce their keepalive, and the server's own faster
    link-silence check is tested in tests/system/test_fleet_e2e.py.)"""
    robot_id = "lwt1"
    status_topic = TOPICS.status(robot_id)
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"lwt-{uuid.uuid4().hex[:6]}")
    client.will_set(status_topic, orjson.dumps({"online": False, "ts": time.time()}), qos=1, retain=True)
    client.connect(server.broker.host, server.broker.port, keepalive=1)
    client.loop_start()
    online = {"online": True, "ts": time.time(), "capabilities": {"sensors": [], "commands": ["stop"]}}
    client.publish(status_topic, orjson.dumps(online), qos=1, retain=True).wait_for_publish(5)
    with server.client() as c:
        wait_robot(c, robot_id, lambda r: r["online"])
        client.loop_stop()  # stop answering keepalives without a DISCONNECT: the broker fires the will
        try:
            wait_robot(c, robot_id, lambda r: not r["online"], timeout=8)
        finally:
            client.socket().close() if client.socket() else None
        # the broker's will did it (not the server's own silence check: this client announced no keepalive)
        offline = wait_for(
            lambda: c.get("/api/events", params={"robot_id": robot_id, "kind": "offline"}).json(),
            5,
            what="offline event stored",
        )
        assert offline[0]["detail"]["source"] == "status"
        assert c.post(f"/api/robots/{robot_id}/commands", json={"command": "stop"}).status_code == 409


def test_ack_after_server_restart_is_recorded(broker, database_url, workdir, mqtt_probe):
    from tests.support.procs import ServerProcess

    s1 = ServerProcess(broker, database_url, workdir)
    s1.start()
    robot = _online_robot(mqtt_probe, s1)
    with s1.client() as c:
        cmd = c.post("/api/robots/r1/commands", json={"command": "stop", "ttl_s": 30}).json()
    assert robot.next_command()["id"] == cmd["id"]
    s1.stop()
    s2 = ServerProcess(broker, database_url, workdir)
    s2.start()
    try:
        robot.ack(cmd["id"], "done", "late")
        with s2.client() as c:
            got = wait_for(lambda: (x := c.get(f"/api/commands/{cmd['id']}").json())["status"] == "done" and x, 5)
            assert got["reason"] == "late" and [a["status"] for a in got["acks"]] == ["done"]
            assert c.get("/api/robots/r1").json()["online"] is True  # retained status restored it
    finally:
        s2.stop()


def test_broker_down_is_503_and_degraded(server, mqtt_probe):
    _online_robot(mqtt_probe, server)
    server.broker.stop()
    with server.client() as c:
        wait_for(lambda: c.get("/api/health").json()["status"] == "degraded", 10, what="degraded health")
        assert c.get("/api/health").json()["mqtt"]["connected"] is False
        r = c.post("/api/robots/r1/commands", json={"command": "stop"})
        assert r.status_code == 503 and "broker" in r.json()["detail"]
