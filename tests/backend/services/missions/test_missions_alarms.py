"""A critical alarm of a robot in a running mission pauses that robot (issue 20): it is stopped, keeps its
path, and carries on from where it stopped once the alarm clears; the mission completes. Real broker, server
and a simulated agent with its disturbances on; the alarm is a real one (the battery rule's threshold moved
above the simulated battery's charge, then back)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import pytest

from tests.support.missions import publish_site, stored_track, wait_ready, wait_state
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, ServerProcess, wait_for

Spawn = Callable[..., AgentProcess]
PATH = [[-0.6, -0.6], [0.6, -0.6], [0.6, 0.0], [-0.6, 0.0], [-0.6, 0.6], [0.6, 0.6]]


def _mission(c, mid):
    return c.get(f"/api/missions/{mid}").json()


def _displacement(track: list[tuple[float, float, float]], start: float, end: float) -> float:
    """How far the robot got from ``start`` to ``end``: the mean of its first five fixes against its last five
    (Lighthouse noise averaged out)."""
    pts = [(x, y) for t, x, y in track if start <= t <= end]
    assert len(pts) >= 10, len(pts)
    (x0, y0), (x1, y1) = (tuple(sum(v) / 5 for v in zip(*part, strict=True)) for part in (pts[:5], pts[-5:]))
    return math.hypot(x1 - x0, y1 - y0)


def _paused(c, mid):
    m = _mission(c, mid)
    return m if any(e["kind"] == "alarm_pause" for e in m["events"]) else None


@pytest.mark.slow
def test_a_critical_alarm_pauses_the_robot_and_it_carries_on_once_cleared(
    server: ServerProcess, spawn_agent: Spawn, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    publish_site(mqtt_probe())
    # every disturbance but the water current, so that a stopped robot stands still and "stopped" can be read
    # from its stored positions
    spawn_agent("al1", "--disturbances", "--no-current", "--battery-start-pct=50", "--start-pose=-0.6,-0.6,0")
    with server.client() as c:
        wait_ready(c, ["al1"])
        body = {"type": "waypoints", "robots": ["al1"], "params": {"paths": {"al1": PATH}}}
        r = c.post("/api/missions", json=body)
        assert r.status_code == 201, r.text
        mid = r.json()["id"]
        assert c.post(f"/api/missions/{mid}/start").status_code == 200
        started = time.time()
        # under way first (so that a pause can be seen): the robot has passed its first corner
        wait_for(lambda: _mission(c, mid)["progress"][0]["fraction"] >= 0.2, 60, interval=0.3, what="under way")
        r = c.put("/api/alarm-rules", json={"kind": "battery_critical", "params": {"below_pct": 60}})
        assert r.status_code == 200, r.text
        wait_for(lambda: _paused(c, mid), 10, interval=0.2, what="the mission pausing its robot")
        paused_at = time.time()
        time.sleep(3.0)  # a paused robot stays in the mission and stands (motors off: it only drifts)
        m = _mission(c, mid)
        assert m["state"] == "running", (m["state"], m["reason"])
        assert not [e for e in m["events"] if e["kind"] == "dropout"], m["events"]
        fraction_paused = m["progress"][0]["fraction"]
        assert fraction_paused < 1.0
        r = c.put("/api/alarm-rules", json={"kind": "battery_critical", "params": {"below_pct": 8}})
        assert r.status_code == 200, r.text
        done = wait_state(c, mid, ("completed", "failed", "paused", "aborted"), timeout=120)
        ended = time.time()
        track = stored_track(c, "al1", started, ended)
    kinds = [e["kind"] for e in done["events"]]
    assert done["state"] == "completed", (done["reason"], done["events"])
    assert "alarm_pause" in kinds and "alarm_resume" in kinds and "dropout" not in kinds, kinds
    # it stood while paused (after its stop took hold) and moved on afterwards: from the stored positions
    assert _displacement(track, started, paused_at) > 0.2  # it could move: the check below can tell
    standing = _displacement(track, paused_at + 1.0, paused_at + 3.0)
    assert standing < 0.02, standing
    assert done["progress"][0]["fraction"] > fraction_paused
