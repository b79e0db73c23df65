"""Commands are rate-limited per caller and robot: 429 past the limit, and the robot never sees the excess."""

from __future__ import annotations

import orjson
import pytest

from tests.backend.api.conftest import new_token
from tests.backend.helpers import TOPICS, ProbeRobot, wait_robot
from tests.support.procs import ServerProcess


@pytest.fixture
def limited_server(broker, database_url, workdir):
    # 3 commands at once, then one every 100 s: the test never waits for a refill
    s = ServerProcess(broker, database_url, workdir, FLEET_COMMAND_RATE_PER_S="0.01", FLEET_COMMAND_BURST="3")
    s.start()
    try:
        yield s
    finally:
        s.stop()


def test_excess_commands_get_429_and_never_reach_the_robot(limited_server, mqtt_probe):
    server = limited_server
    r1, r2 = ProbeRobot(mqtt_probe, "r1"), ProbeRobot(mqtt_probe, "r2")
    r1.status()
    r2.status()
    alice, bob = new_token(server, "operator", "alice"), new_token(server, "operator", "bob")
    with server.client(alice) as a, server.client(bob) as b:
        wait_robot(a, "r2", lambda r: r["online"])
        codes = []
        for i in range(8):
            r = a.post("/api/robots/r1/commands", json={"command": "stop", "source": f"flood-{i}"})
            codes.append(r.status_code)
            if r.status_code == 429:
                assert int(r.headers["retry-after"]) >= 1 and "r1" in r.json()["detail"]
        assert codes == [202] * 3 + [429] * 5
        # per robot: alice may still command r2; per caller: bob may still command r1
        assert a.post("/api/robots/r2/commands", json={"command": "stop"}).status_code == 202
        marker = b.post("/api/robots/r1/commands", json={"command": "stop", "source": "marker"})
        assert marker.status_code == 202
        # the e-stop is never rate-limited
        assert a.post("/api/estop", json={"reason": "still works"}).status_code == 202

    # the server publishes in order on one connection: once the marker arrived, any excess would have too
    topic = TOPICS.cmd("r1")
    r1.probe.wait(lambda m: m.topic == topic and orjson.loads(m.payload)["id"] == marker.json()["id"])
    received = r1.commands_received()
    assert len(received) == 4, received
    with server.client() as admin:
        sources = [admin.get(f"/api/commands/{c['id']}").json()["source"] for c in received]
    assert sources == ["flood-0", "flood-1", "flood-2", "marker"]
