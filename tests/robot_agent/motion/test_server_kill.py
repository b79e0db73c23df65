"""The issue's own check, with the real server: kill -9 the server during a goto, and the robot stops within
1.5 s (1 s without a heartbeat, then the stop). The goal goes through the server's REST API, and the site
the robot checks it against is the one the server publishes (retained) itself."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from fleet_protocol import HEARTBEAT_SILENCE_S
from tests.support.motion import DISTURBED, FakeServer, first_stop_after, moving_at
from tests.support.procs import AgentProcess, ServerProcess, wait_for

pytestmark = pytest.mark.realtime  # wall-clock safety bounds: the realtime lane, alone (docs/testing.md)

Spawn = Callable[..., AgentProcess]


def hear_the_server(srv: FakeServer) -> None:
    """Wait until the real server's heartbeat has been going for a while (the robot, online before, hears it)."""
    srv.probe.subscribe("fleet/heartbeat")
    wait_for(
        lambda: len([m for m in srv.probe.messages if m.topic == "fleet/heartbeat"]) >= 3,
        10,
        what="the real server's heartbeat",
    )


def test_killing_the_server_stops_a_goal(server: ServerProcess, spawn_agent: Spawn, fake_server: FakeServer) -> None:
    srv = fake_server  # only watches: the heartbeat and the site are the real server's
    spawn_agent("k1", *DISTURBED, "--start-pose=-1.4,0,0")
    srv.wait_online("k1")
    hear_the_server(srv)
    with server.client() as c:
        wait_for(lambda: c.get("/api/robots/k1").json().get("online"), 20, what="the server to see k1")
        r = c.post("/api/robots/k1/commands", json={"command": "goto", "args": {"x": 1.4, "y": 0.0}, "ttl_s": 5})
        assert r.status_code in (200, 202), r.text
        cid = r.json()["id"]
    accepted = srv.ack("k1", cid, "accepted", 10)
    assert accepted["reason"] == "checked against site v1", accepted  # the server's own site
    srv.wait_motion("k1", cid, lambda e: e["ts"] > accepted["ts"] + 1.0 and e["data"]["setpoint"]["linear"] > 0.05)
    server.kill()
    last_beat = max(m.at for m in srv.probe.messages if m.topic == "fleet/heartbeat")
    killed_at = time.time()
    final = srv.final_ack("k1", cid, 10)
    assert final["status"] == "failed" and final["reason"].startswith("unsupervised"), final
    reports = srv.motion("k1", cid)
    assert moving_at(reports, killed_at)
    stopped = first_stop_after(reports, last_beat)
    assert stopped is not None
    took = stopped - killed_at
    print(f"stopped {took:.3f} s after kill -9 ({stopped - last_beat:.3f} s after the last heartbeat heard)")
    assert took <= HEARTBEAT_SILENCE_S + 0.5


def test_the_server_records_how_goals_end(server: ServerProcess, spawn_agent: Spawn, fake_server: FakeServer) -> None:
    srv = fake_server
    spawn_agent("k2", "--start-pose=0,0,0")
    srv.wait_online("k2")
    hear_the_server(srv)
    with server.client() as c:
        wait_for(lambda: c.get("/api/robots/k2").json().get("online"), 20, what="the server to see k2")
        ids = {}
        for name, args in (("done", {"x": 0.15, "y": 0.0}), ("failed", {"x": 1.5, "y": 0.0, "timeout_s": 0.5})):
            r = c.post("/api/robots/k2/commands", json={"command": "goto", "args": args, "ttl_s": 5})
            assert r.status_code in (200, 202), r.text
            ids[name] = r.json()["id"]
            assert srv.final_ack("k2", ids[name], 30)["status"] == name
        for status, cid in ids.items():
            wait_for(
                lambda cid=cid, status=status: c.get(f"/api/commands/{cid}").json()["status"] == status,
                10,
                what=f"the server to record {status}",
            )
        assert c.get(f"/api/commands/{ids['failed']}").json()["reason"].startswith("timeout")
