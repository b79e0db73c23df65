"""A mission holds its robots' control leases (issue 20): taken when it starts or resumes (all or none; the
starter's own lease passes to it; 409 naming whoever else drives one), kept while it runs however long it
takes (here longer than several lapses), released when it pauses, when a robot drops out and when it ends.
Pause needs no lease. Real broker, server (authentication on, a 2 s lapse) and two simulated agents."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import httpx

from tests.backend.helpers import audit_trail, operator_token, wait_robot
from tests.backend.services.control.test_leases import DRIVE
from tests.support.missions import publish_site, wait_ready, wait_state
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker, ServerProcess, wait_for

LAPSE_S = 2.0
PATHS = {"ml-1": [[-0.6, -0.6], [0.9, -0.6]], "ml-2": [[-0.6, 0.6], [0.9, 0.6]]}
GOTO = {"command": "goto", "args": {"x": 0.0, "y": 0.0, "tolerance_m": 0.05}}


def _holder(c: httpx.Client, robot: str) -> str | None:
    lease = c.get(f"/api/robots/{robot}/lease").json()
    return lease["holder_name"] if lease else None


def _refused_by(c: httpx.Client, robot: str, body: dict[str, Any], holder: str) -> None:
    r = c.post(f"/api/robots/{robot}/commands", json=body)
    assert r.status_code == 409, r.text
    assert r.json()["code"] == "lease_held" and f"driven by {holder}" in r.json()["detail"], r.text


def test_a_mission_holds_its_robots_leases_while_it_runs(
    broker: Broker,
    database_url: str,
    workdir: Any,
    spawn_agent: Callable[..., AgentProcess],
    mqtt_probe: Callable[..., MqttProbe],
) -> None:
    server = ServerProcess(broker, database_url, workdir, FLEET_LEASE_LAPSE_S=str(LAPSE_S))
    server.start()
    try:
        publish_site(mqtt_probe())
        spawn_agent("ml-1", "--start-pose=-0.6,-0.6,0")
        spawn_agent("ml-2", "--start-pose=-0.6,0.6,0")
        alice, _ = operator_token(server, "alice")
        bob, _ = operator_token(server, "bob")
        with server.client(alice) as a, server.client(bob) as b, server.client() as admin:
            wait_ready(admin, list(PATHS))
            body = {"type": "waypoints", "name": "sweep", "robots": list(PATHS), "params": {"paths": PATHS}}
            r = a.post("/api/missions", json=body)
            assert r.status_code == 201, r.text
            mid = r.json()["id"]
            mission = "mission sweep (started by alice)"

            # alice drives ml-1, bob ml-2: the start is refused naming bob, and nothing changed (all or none)
            assert a.post("/api/robots/ml-1/commands", json=DRIVE).status_code == 202
            assert b.post("/api/robots/ml-2/commands", json=DRIVE).status_code == 202
            refused = a.post(f"/api/missions/{mid}/start")
            assert refused.status_code == 409 and "driven by bob" in refused.json()["detail"], refused.text
            assert a.get(f"/api/missions/{mid}").json()["state"] == "draft"
            assert (_holder(admin, "ml-1"), _holder(admin, "ml-2")) == ("alice", "bob")

            # bob lets go: the mission starts; alice's own lease passes to it
            assert b.delete("/api/robots/ml-2/lease").status_code == 204
            assert a.post(f"/api/missions/{mid}/start").status_code == 200
            started = time.time()
            assert (_holder(admin, "ml-1"), _holder(admin, "ml-2")) == (mission, mission)
            robot = admin.get("/api/robots/ml-1").json()
            assert robot["lease"]["holder_name"] == mission  # what the robot list shows ("driven by")
            # nobody else drives its robots, not even its starter, by drive or goto
            for c, rid, cmd in ((b, "ml-1", DRIVE), (b, "ml-2", GOTO), (a, "ml-1", DRIVE)):
                _refused_by(c, rid, cmd, mission)
            assert "pause or abort the mission" in b.post("/api/robots/ml-1/commands", json=DRIVE).json()["detail"]

            # over two lapses later (the robots drive one leg each: no drive command since): still held
            time.sleep(max(0.0, 2.5 * LAPSE_S - (time.time() - started)))
            m = a.get(f"/api/missions/{mid}").json()
            assert m["state"] == "running" and all(p["fraction"] < 1.0 for p in m["progress"]), m["progress"]
            _refused_by(b, "ml-1", DRIVE, mission)
            assert (_holder(admin, "ml-1"), _holder(admin, "ml-2")) == (mission, mission)

            # pause needs no lease (bob pauses alice's mission); a paused mission holds nothing
            assert b.post(f"/api/missions/{mid}/pause").status_code == 200
            assert (_holder(admin, "ml-1"), _holder(admin, "ml-2")) == (None, None)
            assert b.post("/api/robots/ml-1/commands", json=DRIVE).status_code == 202  # bob may drive it now
            refused = a.post(f"/api/missions/{mid}/resume")
            assert refused.status_code == 409 and "driven by bob" in refused.json()["detail"], refused.text
            assert a.get(f"/api/missions/{mid}").json()["state"] == "paused"
            assert b.post("/api/robots/ml-1/commands", json={"command": "stop"}).status_code == 202
            assert b.delete("/api/robots/ml-1/lease").status_code == 204
            assert a.post(f"/api/missions/{mid}/resume").status_code == 200
            resumed = "mission sweep (resumed by alice)"
            assert (_holder(admin, "ml-1"), _holder(admin, "ml-2")) == (resumed, resumed)

            # a robot that drops out (held) is let go at once; the other stays the mission's
            assert admin.put("/api/robots/ml-2/hold", json={"reason": "test"}).status_code == 200
            wait_for(lambda: _holder(admin, "ml-2") is None, 5, interval=0.2, what="ml-2's lease released")
            assert _holder(admin, "ml-1") == resumed
            assert admin.delete("/api/robots/ml-2/hold").status_code == 200
            # ... and the mission's end releases the rest
            done = wait_state(a, mid, ("completed", "failed", "aborted"), timeout=60)
            assert done["state"] == "failed", done  # a waypoints mission with a robot dropped out
            wait_for(lambda: _holder(admin, "ml-1") is None, 5, interval=0.2, what="ml-1's lease released")
            assert b.post("/api/robots/ml-1/commands", json=DRIVE).status_code == 202
            wait_robot(admin, "ml-1", lambda x: x["lease"]["holder_name"] == "bob")

        leases = [
            (e["actor_name"], e["action"], e["robot_id"], e["detail"].get("from"))
            for e in audit_trail(server)
            if e["action"].startswith("lease_") and e["actor_name"].startswith("mission")
        ]
        assert leases == [
            (mission, "lease_take", "ml-1", "alice"),
            (mission, "lease_take", "ml-2", None),
            (mission, "lease_release", "ml-1", None),
            (mission, "lease_release", "ml-2", None),
            (resumed, "lease_take", "ml-1", None),
            (resumed, "lease_take", "ml-2", None),
            (resumed, "lease_release", "ml-2", None),
            (resumed, "lease_release", "ml-1", None),
        ], leases
        legs = [e for e in audit_trail(server, action="command") if e["actor_name"].startswith("mission")]
        assert legs and all(e["detail"]["command"] == "follow_path" for e in legs)
        assert {e["actor"] for e in legs} == {e["actor"] for e in audit_trail(server, actor="alice")}  # her subject
    finally:
        server.stop()
