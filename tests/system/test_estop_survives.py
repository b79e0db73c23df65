"""The e-stop survives anything (issue 28): a broker that loses its retained messages (killed with no
persistence, or the demo's embedded broker, which has none), a server killed with it, robots that reboot.
Real Mosquitto (or the demo's amqtt broker), real servers, real simulated agents, the real
``fleet-agent estop``. The rules are in backend/services/safety/latches.py and docs/safety.md."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import orjson

from fleet_protocol import EStop, dumps, new_command
from tests.backend.helpers import TOPICS, wait_robot, ws_collect
from tests.support.mqtt import MqttProbe
from tests.support.procs import VENV_BIN, Broker, ServerProcess, base_env, free_port, wait_for, wait_port

ROOT = Path(__file__).resolve().parents[2]
DRIVE = {"command": "move_forward", "args": {"speed": 0.5, "duration_s": 0.5}}


def _json(m: Any) -> dict[str, Any]:
    return orjson.loads(m.payload)  # type: ignore[no-any-return]


def _synced(server: ServerProcess, at_least: int = 1) -> None:
    """The server has compared its latches with what the broker holds since it (re)connected."""
    with server.client() as c:
        wait_for(lambda: c.get("/api/stats").json()["latches"]["synced"] >= at_least, 15, what="latches synced")


def _after_the_sync(server: ServerProcess, watch: MqttProbe) -> None:
    """Wait for the sync, then for a heartbeat the server sent after it: what it published on the e-stop's
    topic during the sync (on the same connection, in order) has reached ``watch`` by then."""
    _synced(server)
    synced_at = time.time()
    watch.wait(lambda m: m.topic == TOPICS.heartbeat() and _json(m)["ts"] > synced_at, 5)


def _published_estops(watch: MqttProbe) -> list[str]:
    return [_json(m)["id"] for m in watch.messages if m.topic == TOPICS.estop()]


def _retained(broker: Any, topic: str) -> dict[str, Any]:
    """What the broker holds on ``topic`` now (a new subscriber gets it at once)."""
    probe = MqttProbe(broker.host, broker.port, [topic])
    try:
        return _json(probe.wait(lambda m: m.topic == topic and m.retain, 5))
    finally:
        probe.close()


def _direct_drive_refused(probe: MqttProbe, robot_id: str) -> None:
    """A drive published straight to the robot (no server in the way) is refused by the robot itself."""
    cmd = new_command("move_forward", {"speed": 0.5, "duration_s": 0.5})
    probe.publish(TOPICS.cmd(robot_id), dumps(cmd))
    ack = probe.wait(lambda m: m.topic == TOPICS.ack(robot_id) and _json(m)["id"] == cmd.id, 10)
    assert (_json(ack)["status"], _json(ack)["reason"]) == ("rejected", "e-stop engaged")


def test_a_broker_killed_right_after_an_estop_and_the_server_with_it_leave_everyone_latched(
    broker, database_url, workdir, spawn_agent, mqtt_probe
):
    server = ServerProcess(broker, database_url, workdir)
    server.start()
    try:
        agent = spawn_agent("survivor-1")
        with server.client() as c:
            wait_robot(c, "survivor-1", lambda r: r["online"])
            r = c.post("/api/estop", json={"reason": "robot at the wall"})
            assert r.status_code == 202, r.text
            estop_id = r.json()["id"]
        # right after: the broker (no persistence: its retained e-stop is gone), the server and the robot die
        broker.kill()
        server.kill()
        agent.kill()
        broker.start()
        server.start()
        with server.client() as c:  # the server: latched from the first answer on
            state = c.get("/api/estop").json()
            assert (state["engaged"], state["id"], state["reason"]) == (True, estop_id, "robot at the wall")
        # the dashboard: the live socket's first snapshot
        messages, _ = asyncio.run(
            ws_collect(
                server.ws_url,
                {"type": "subscribe", "robots": ["*"], "streams": ["position"]},
                lambda ms: any(m["type"] == "snapshot" for m in ms),
            )
        )
        snapshot = next(m for m in messages if m["type"] == "snapshot")
        assert snapshot["estop"]["engaged"] is True and snapshot["estop"]["id"] == estop_id
        # the broker: the latch is back, retained, with its id
        _synced(server)
        retained = _retained(broker, TOPICS.estop())
        assert retained["engaged"] is True and retained["id"] == estop_id
        # a robot that reboots comes up latched, and refuses a drive sent straight to it
        probe = mqtt_probe(TOPICS.ack("survivor-1"))
        spawn_agent("survivor-1")
        with server.client() as c:
            wait_robot(c, "survivor-1", lambda r: r["online"] and r["estop"])
            refused = c.post("/api/robots/survivor-1/commands", json=DRIVE)
            assert refused.status_code == 409 and refused.json()["code"] == "estop_engaged", refused.text
        _direct_drive_refused(probe, "survivor-1")
    finally:
        server.stop()


def test_a_hold_survives_a_broker_and_a_server_killed_together(broker, database_url, workdir, spawn_agent):
    server = ServerProcess(broker, database_url, workdir)
    server.start()
    try:
        spawn_agent("held-1")
        with server.client() as c:
            wait_robot(c, "held-1", lambda r: r["online"])
            assert c.put("/api/robots/held-1/hold", json={"reason": "tangled"}).status_code == 200
        broker.kill()
        server.kill()
        broker.start()
        server.start()
        with server.client() as c:
            assert c.get("/api/robots/held-1").json()["hold"]["reason"] == "tangled"
            wait_robot(c, "held-1", lambda r: r["online"])  # the robot reconnected to the new broker
            refused = c.post("/api/robots/held-1/commands", json=DRIVE)
            assert refused.status_code == 409 and refused.json()["code"] == "robot_held", refused.text
            _synced(server)
            retained = _retained(broker, TOPICS.hold("held-1"))
            assert retained["held"] is True and retained["reason"] == "tangled"
            # released, the same robot drives: the refusal above was the hold's
            assert c.delete("/api/robots/held-1/hold").status_code == 200
            done = c.post("/api/robots/held-1/commands", params={"wait": 5}, json=DRIVE)
            assert done.status_code == 200 and done.json()["status"] == "done", done.text
    finally:
        server.stop()


def _fleet_agent_estop(broker: Broker, *args: str) -> dict[str, Any]:
    """``fleet-agent estop`` straight to the broker (no server), then what the broker holds."""
    out = subprocess.run(
        [str(VENV_BIN / "fleet-agent"), "estop", "--broker", broker.url, "--username", "", *args],
        env=base_env(),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 0, out.stderr
    return _retained(broker, TOPICS.estop())


def test_the_server_puts_back_only_a_newer_latch_and_never_a_release_nobody_pressed(
    broker, database_url, workdir, mqtt_probe
):
    server = ServerProcess(broker, database_url, workdir)
    server.start()
    try:
        with server.client() as c:
            assert c.post("/api/estop").status_code == 202
            assert c.post("/api/estop/release").status_code == 202
        server.stop()  # its stored state: released
        # 1. the base station's e-stop, newer, while the server is away: the server takes it, publishes nothing
        latch = _fleet_agent_estop(broker, "--reason", "from the base station")
        watch = mqtt_probe(TOPICS.estop(), TOPICS.heartbeat())
        watch.wait(lambda m: m.retain, 5)
        server.start()
        _after_the_sync(server, watch)
        with server.client() as c:
            state = c.get("/api/estop").json()
            assert (state["engaged"], state["id"], state["reason"]) == (True, latch["id"], "from the base station")
        assert _published_estops(watch) == [latch["id"]]  # the server's stored release was not replayed
        server.stop()
        # 2. a release pressed on the broker after the server's latch: taken; the latch is not put back
        release = _fleet_agent_estop(broker, "--release")
        server.start()
        _after_the_sync(server, watch)
        with server.client() as c:
            state = c.get("/api/estop").json()
            assert (state["engaged"], state["id"]) == (False, release["id"])
        assert _published_estops(watch) == [latch["id"], release["id"]]
        watch.close()
        # 3. a broker restarted with an older state (a release from before the server's latch): latched again
        with server.client() as c:
            mine = c.post("/api/estop", json={"reason": "newer"}).json()
        server.stop()
        broker.kill()
        broker.start()
        old = EStop(ts=mine["ts"] - 60, id="old-release", engaged=False, reason="from an older save")
        mqtt_probe().publish(TOPICS.estop(), dumps(old), retain=True)
        server.start()
        _synced(server)
        with server.client() as c:
            assert c.get("/api/estop").json()["id"] == mine["id"]
        assert _retained(broker, TOPICS.estop())["id"] == mine["id"]
        # 4. the server's release against an older latch the broker holds: the latch stands (press release again)
        with server.client() as c:
            released = c.post("/api/estop/release").json()
        server.stop()
        broker.kill()
        broker.start()
        old = EStop(ts=released["ts"] - 60, id="old-latch", engaged=True, reason="from an older save")
        mqtt_probe().publish(TOPICS.estop(), dumps(old), retain=True)
        server.start()
        _synced(server)
        with server.client() as c:
            state = c.get("/api/estop").json()
            assert (state["engaged"], state["id"]) == (True, "old-latch")
        assert _retained(broker, TOPICS.estop())["id"] == "old-latch"
    finally:
        server.stop()


class EmbeddedBroker:
    """The demo's fallback broker (scripts/embedded_broker.py, amqtt: no persistence at all)."""

    def __init__(self, workdir: Path) -> None:
        self.host = "127.0.0.1"
        self.port = free_port()
        self.log = workdir / "embedded-broker.log"
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"

    def start(self) -> None:
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                [
                    sys.executable,
                    str(ROOT / "scripts" / "embedded_broker.py"),
                    "--host",
                    self.host,
                    "--port",
                    str(self.port),
                ],
                stdout=log,
                stderr=subprocess.STDOUT,
                env=base_env(),
            )
        wait_port(self.port, 20)

    def kill(self) -> None:
        if self.proc is not None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(5)
            self.proc = None


def test_the_demos_embedded_broker_restarted_gets_the_latch_back_at_the_reconnection(workdir, database_url):
    from tests.support.procs import AgentProcess

    broker = EmbeddedBroker(workdir)
    broker.start()
    # as scripts/demo.py runs it: authentication off, MQTT 3.1.1 (amqtt has no v5)
    server = ServerProcess(broker, database_url, workdir, FLEET_AUTH="off", FLEET_MQTT_PROTOCOL="3.1.1")  # type: ignore[arg-type]
    agents: list[AgentProcess] = []
    try:
        server.start()
        with server.client() as c:
            estop_id = c.post("/api/estop", json={"reason": "demo"}).json()["id"]
        _synced(server)
        broker.kill()
        broker.start()  # empty; the server is not restarted: it reconnects by itself
        _synced(server, 2)
        retained = _retained(broker, TOPICS.estop())
        assert retained["engaged"] is True and retained["id"] == estop_id
        agent = AgentProcess("demo-1", broker, workdir)  # type: ignore[arg-type]
        agents.append(agent)
        agent.start()
        probe = MqttProbe(broker.host, broker.port, [TOPICS.ack("demo-1")])
        try:
            with server.client() as c:
                wait_robot(c, "demo-1", lambda r: r["online"] and r["estop"])
            _direct_drive_refused(probe, "demo-1")
        finally:
            probe.close()
    finally:
        for agent in agents:
            agent.stop()
        server.stop()
        broker.kill()
