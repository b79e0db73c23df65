"""Only robots an admin registered speak on the old framework's topics (issue 29 #2).

The old framework publishes anonymously on shared topics and names its robot in the payload: before
registration, anything that could write those topics was stored as any robot's data (20 of 20 messages naming
an online robot of the new framework became its position), could turn a robot into a legacy one, and a
robot's own status claiming ``legacy: true`` sent the drives meant for it to the shared topic every old robot
obeys. Measured through the shipped broker config with its ACL (legacy mode: anonymous clients allowed on the
old topics), then across two replicas, the CLI and a restart."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import orjson
import pytest

from fleet_protocol import LEGACY_POSITION_TOPIC, Topics, encode_telemetry
from tests.backend.helpers import register_legacy, wait_robot
from tests.backend.services.legacy.test_relay import SERVER_PASSWORD, _server
from tests.deploy.test_mosquitto import DEPLOY, Client, ShippedBroker, _passwd, shipped_broker
from tests.support.procs import TEST_ADMIN_TOKEN, VENV_BIN, ServerProcess, base_env, replica_pair, wait_for
from tests.support.seed_robot import SeedRobot

TOPICS = Topics()
ROBOT_PASSWORD = "pw-newbot-registrations"


@pytest.fixture
def acl_broker() -> Iterator[ShippedBroker]:
    files = {
        "passwd": _passwd({"fleet-server": SERVER_PASSWORD, "newbot": ROBOT_PASSWORD}),
        "acl": (DEPLOY / "mosquitto" / "acl.example").read_text(),
    }
    with shipped_broker("legacy", files) as b:
        yield b


def _legacy_position(robot_id: str, x: float) -> bytes:
    return orjson.dumps({"robot_id": robot_id, "position": f"{x},9,0"})


def _rejected(c: Any) -> int:
    return int(c.get("/api/health").json()["rejects"]["by_reason"].get("legacy_unregistered", 0))


def test_the_old_topics_speak_only_for_registered_robots(acl_broker: ShippedBroker, database_url, workdir) -> None:
    port = acl_broker.port
    server = _server(port, database_url, workdir)
    newbot = Client(port, username="newbot", password=ROBOT_PASSWORD, subscribe=(TOPICS.cmd("newbot"),))
    anonymous = Client(port)  # anyone who may write the old framework's anonymous topics
    seed = SeedRobot("127.0.0.1", port, "old-1")  # listens on the shared topic, as every seed robot does
    try:
        newbot.wait_connected()
        anonymous.wait_connected()
        status = {
            "online": True,
            "ts": time.time(),
            "agent_version": "t",
            "legacy": True,  # a claim: it must not make the robot one of the old framework
            "capabilities": {"sensors": ["position"], "commands": ["drive", "stop"]},
        }
        newbot.publish(TOPICS.status("newbot"), orjson.dumps(status), retain=True)
        newbot.publish(TOPICS.telemetry("newbot", "position"), encode_telemetry(0, {"x": 1.0, "y": 1.0}))
        with server.client() as c:
            robot = wait_robot(c, "newbot", lambda r: r["online"] and r["position"] is not None)
            assert robot["legacy"] is False and robot["legacy_unit"] == []
            for i in range(20):  # all on one connection at QoS 1: the server handles them in this order
                anonymous.publish(LEGACY_POSITION_TOPIC, _legacy_position("newbot", i))
            for i in range(5):
                anonymous.publish(LEGACY_POSITION_TOPIC, _legacy_position("ghost", i))
            # a registered robot is heard (so the refusals above are the registration's doing, not a dead path)
            register_legacy(c, "old-1")
            anonymous.publish(LEGACY_POSITION_TOPIC, _legacy_position("old-1", 3))
            wait_robot(c, "old-1", lambda r: r["online"] and r["legacy"] and r["position"] is not None)

            assert _rejected(c) == 25
            points = c.get("/api/robots/newbot/telemetry").json()["points"]
            assert [(p["data"]["x"], p["data"]["y"]) for p in points] == [(1.0, 1.0)]  # its own sample only
            assert c.get("/api/robots/ghost").status_code == 404
            assert "legacy_unregistered" in server.output()  # logged too

            # a drive meant for the new robot goes to its own command topic, never to the shared one
            t0 = time.time()
            turn = {"command": "drive", "args": {"linear": 0.0, "angular": 1.0, "duration_s": 0.3}}
            assert c.post("/api/robots/newbot/commands", json=turn).status_code == 202
            newbot.wait_for_topic(TOPICS.cmd("newbot"))
            forward = {"command": "move_forward", "args": {"duration_s": 0.3}}
            assert c.post("/api/robots/old-1/commands", json=forward).status_code == 202
            seed.wait_heard("move_forward", t0)  # the shared topic carries drives: it would have heard a turn
            seed.wait_heard("stop", t0)
            assert "turn_left" not in [h.command for h in seed.commands(t0)]

            # removed: it hears "stop", shows offline, and its messages are refused again
            stop_at = time.time()
            gone = c.delete("/api/robots/old-1/legacy")
            assert gone.status_code == 200 and gone.json()["legacy"] is False and not gone.json()["online"]
            seed.wait_heard("stop", stop_at)
            anonymous.publish(LEGACY_POSITION_TOPIC, _legacy_position("old-1", 4))
            wait_for(lambda: _rejected(c) == 26, 5, what="the removed robot's message refused")
            assert not c.get("/api/robots/old-1").json()["online"]
            # a robot online with the agent cannot be registered (its drives would go to the old topics)
            refused = c.put("/api/robots/newbot/legacy", json={"listens_on": "shared"})
            assert refused.status_code == 409 and "online with the agent" in refused.json()["detail"]
            assert c.put("/api/robots/bad%20id/legacy", json={}).status_code == 422
            wanted = {("legacy_register", "old-1"), ("legacy_unregister", "old-1")}
            wait_for(lambda: wanted <= {(e["action"], e["robot_id"]) for e in c.get("/api/audit").json()}, 5)
    finally:
        seed.close()
        anonymous.close()
        newbot.close()
        server.stop()


def _cli(server: ServerProcess, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(VENV_BIN / "fleet-server"), "robots", *args, "--server", server.base_url],
        env=base_env(FLEET_ADMIN_TOKEN=TEST_ADMIN_TOKEN),
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_a_registration_reaches_every_replica_and_outlives_a_restart(broker, pg_url, workdir: Path, mqtt_probe) -> None:
    one, two = replica_pair(broker, pg_url, workdir, ("1", "2"))
    for s in (one, two):
        s.start()
    anonymous = mqtt_probe()
    try:
        with one.client() as c1, two.client() as c2:
            register_legacy(c1, "old-r")
            wait_robot(c2, "old-r", lambda r: r["legacy"], timeout=5)  # the other replica re-reads it
            for i in range(4):  # the replicas share the legacy topics: each takes some
                anonymous.publish(LEGACY_POSITION_TOPIC, _legacy_position("old-r", i), qos=1)
            wait_for(lambda: len(c1.get("/api/robots/old-r/telemetry").json()["points"]) == 4, 10, what="4 stored")

            done = _cli(two, "legacy-remove", "old-r")
            assert done.returncode == 0 and "no longer registered" in done.stdout, done.stderr
            wait_robot(c1, "old-r", lambda r: not r["legacy"], timeout=5)
            for i in range(4):
                anonymous.publish(LEGACY_POSITION_TOPIC, _legacy_position("old-r", 10 + i), qos=1)
            wait_for(lambda: _rejected(c1) + _rejected(c2) == 4, 10, what="4 refused, by whichever replica")
            assert len(c1.get("/api/robots/old-r/telemetry").json()["points"]) == 4

            done = _cli(one, "legacy-add", "old-r", "--listens-on", "own")
            assert done.returncode == 0 and "registered" in done.stdout, done.stderr
            wait_robot(c2, "old-r", lambda r: r["legacy"] and r["legacy_listens_on"] == "own", timeout=5)
            assert _cli(one, "legacy-remove", "never-seen").returncode == 1
        one.stop()
        one.start()  # registrations are stored: known at once after a restart (and after an upgrade)
        with one.client() as c1:
            robot = c1.get("/api/robots/old-r").json()
            assert robot["legacy"] is True and robot["legacy_listens_on"] == "own"
    finally:
        for s in (one, two):
            s.stop()
