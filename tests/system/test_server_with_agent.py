"""The server with a real simulated robot agent process (robot_agent, helper AGENT)."""

from __future__ import annotations

import asyncio
import math

import pytest

from tests.backend.helpers import wait_robot, ws_collect
from tests.support.procs import wait_for

pytest.importorskip("robot_agent.cli", reason="robot agent not available yet")


def test_agent_telemetry_command_and_shutdown(server, spawn_agent):
    agent = spawn_agent("sim1", "--start-pose", "0,0,0")
    with server.client() as c:
        robot = wait_robot(
            c,
            "sim1",
            lambda r: r["online"] and r["position"] is not None and "move_forward" in r["capabilities"]["commands"],
            timeout=20,
        )
        assert robot["legacy"] is False and robot["agent_version"]
        start = robot["position"]
        wait_for(lambda: len(c.get("/api/robots/sim1/telemetry").json()["points"]) >= 5, 10, what="stored points")

        msgs, _ = asyncio.run(
            ws_collect(
                server.ws_url,
                {"type": "subscribe", "robots": ["sim1"], "streams": ["position"]},
                lambda m: sum(x["type"] == "telemetry" for x in m) >= 3,
            )
        )
        assert msgs[0]["type"] == "snapshot"
        assert all(m["robot_id"] == "sim1" for m in msgs if m["type"] == "telemetry")

        r = c.post(
            "/api/robots/sim1/commands?wait=5",
            json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 1.0}},
        )
        assert r.status_code == 200, r.text
        assert r.json()["status"] == "done", r.json()
        moved = wait_robot(
            c,
            "sim1",
            lambda x: math.hypot(x["position"]["x"] - start["x"], x["position"]["y"] - start["y"]) > 0.1,
        )
        assert moved["position"]["ts"] > start["ts"]
        agent.stop()
        wait_robot(c, "sim1", lambda x: not x["online"], timeout=10)
        assert c.post("/api/robots/sim1/commands", json={"command": "stop"}).status_code == 409
