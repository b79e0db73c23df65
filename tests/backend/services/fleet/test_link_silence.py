"""The server's own watch on a robot's link (backend/services/fleet/registry.py, ``link-silent``): a robot that
announced its keepalive and then sends nothing is shown offline 1.5 x that keepalive after its last message,
whatever the broker does. Here the broker never gives up on it (the probe's own MQTT connection stays alive),
so only the server's watch can take it offline: tests/system/test_fleet_e2e.py's frozen Wi-Fi link races it
against the broker's Last Will, which may come first."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from tests.backend.helpers import ProbeRobot
from tests.support.mqtt import MqttProbe
from tests.support.procs import ServerProcess, wait_for

KEEPALIVE_S = 2.0  # messages come every 0.4 s: a loaded server has 2.6 s of slack before the first false alarm


def _offline_events(c: Any, robot_id: str) -> list[dict[str, Any]]:
    return [e for e in c.get("/api/events", params={"robot_id": robot_id}).json() if e["kind"] == "offline"]


def test_a_robot_silent_for_one_and_a_half_keepalives_is_shown_offline_by_the_server(
    server: ServerProcess, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    robot = ProbeRobot(mqtt_probe, "quiet-1")
    robot.status(keepalive_s=KEEPALIVE_S)
    with server.client() as c:
        talked = time.time()
        seq = 0
        # a robot talking, for longer than 1.5 x keepalive since its status: kept online by its telemetry alone
        while time.time() - talked < 2 * KEEPALIVE_S:
            time.sleep(0.4)
            robot.telemetry(seq, {"x": 0.0, "y": 0.0})
            seq += 1
        last = time.time()  # then silence: no telemetry, no status, the MQTT connection alive
        assert c.get("/api/robots/quiet-1").json()["online"] and _offline_events(c, "quiet-1") == []
        wait_for(lambda: not c.get("/api/robots/quiet-1").json()["online"], 10, what="quiet-1 shown offline")
        silent_for = time.time() - last
        events = _offline_events(c, "quiet-1")
        assert [e["detail"].get("source") for e in events] == ["link-silent"], events
        assert silent_for > 1.5 * KEEPALIVE_S - 0.2, silent_for  # not before its keepalive allows
        assert events[0]["ts"] - last > 1.5 * KEEPALIVE_S - 0.2, events[0]["ts"] - last
        robot.telemetry(seq, {"x": 0.0, "y": 0.0})  # its next message: online again (the link was back)
        wait_for(lambda: c.get("/api/robots/quiet-1").json()["online"], 5, what="quiet-1 online again")
