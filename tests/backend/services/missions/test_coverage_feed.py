"""The swept area on the live socket (issue 30): a running mission's plan and swept area are pushed, and a
client that connects mid-mission gets them in its snapshot; an ended mission leaves the snapshot. Real parts:
Mosquitto, the server and a simulated agent with its disturbances on."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

import pytest
from shapely.geometry import box, shape

from tests.backend.helpers import ws_collect
from tests.support.missions import publish_site, wait_ready, wait_state
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, ServerProcess

AREA = [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]
EVERYTHING = {"type": "subscribe", "robots": ["*"], "streams": ["position"]}


def _swept(messages: list[dict[str, Any]], mission_id: str) -> list[dict[str, Any]]:
    return [m for m in messages if m["type"] == "mission_coverage" and m["mission_id"] == mission_id]


def _snapshot(server: ServerProcess) -> dict[str, Any]:
    messages, _ = asyncio.run(
        ws_collect(server.ws_url, EVERYTHING, lambda ms: any(m["type"] == "snapshot" for m in ms))
    )
    return next(m for m in messages if m["type"] == "snapshot")


@pytest.mark.slow
def test_a_running_missions_swept_area_is_pushed_and_in_the_snapshot(
    server: ServerProcess, spawn_agent: Callable[..., AgentProcess], mqtt_probe: Callable[..., MqttProbe]
) -> None:
    publish_site(mqtt_probe())
    spawn_agent("cf1", "--disturbances", "--start-pose=-0.4,-0.4,1.57")
    with server.client() as c:
        wait_ready(c, ["cf1"])
        made = c.post(
            "/api/missions",
            json={"type": "coverage", "robots": ["cf1"], "params": {"area": AREA, "sweep_width_m": 0.25}},
        )
        assert made.status_code == 201, made.text
        mid = made.json()["id"]
        assert _snapshot(server)["missions"] == []  # a draft is not shown

        started: dict[str, float] = {}

        def start() -> None:
            started["at"] = time.monotonic()
            assert c.post(f"/api/missions/{mid}/start").status_code == 200

        def swept_some(ms: list[dict[str, Any]]) -> bool:
            return any(shape(m["geometry"]).area > 0.01 for m in _swept(ms, mid))

        messages, _ = asyncio.run(ws_collect(server.ws_url, EVERYTHING, swept_some, timeout=60, on_open=start))
        seen_for = time.monotonic() - started["at"]
        # the plan came with the mission's own push, running, with the robot's path
        running = [m["mission"] for m in messages if m["type"] == "mission" and m["mission"]["id"] == mid]
        assert running and running[0]["state"] == "running" and len(running[0]["parts"][0]["path"]) > 1
        pushes = _swept(messages, mid)
        # pushed only when it changed, looked at once a second: never more often than that
        assert len(pushes) <= seen_for / 1.0 + 2, (len(pushes), seen_for)
        last = shape(pushes[-1]["geometry"])
        assert last.is_valid and box(-0.6, -0.6, 0.6, 0.6).contains(last)  # inside the mission's area
        assert pushes[-1]["covered_fraction"] > 0 and pushes[-1]["state"] == "running"

        # a client connecting now gets the mission and its swept area at once
        snap = _snapshot(server)
        assert [m["id"] for m in snap["missions"]] == [mid]
        assert "events" not in snap["missions"][0] and snap["missions"][0]["parts"]
        assert shape(snap["coverage"][mid]).area >= last.area - 1e-9

        assert c.post(f"/api/missions/{mid}/abort").status_code == 200
        wait_state(c, mid, ("aborted",), 15)
        # ended: the snapshot shows it no more (it did a moment ago)
        snap = _snapshot(server)
        assert snap["missions"] == [] and snap["coverage"] == {}
