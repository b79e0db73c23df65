"""A run's separation figures (GET /api/runs/{id}, summary.separation) from what the server stored: two
robots fed over MQTT pass each other at a known distance, their samples interleaved in time (never at the same
instants), and one robot's filter reports an intervention. Then two robots that pass far apart: nothing to
count, by the same counter that just counted. Real server, broker and database."""

from __future__ import annotations

import time

import pytest

from tests.backend.helpers import ProbeRobot, publish_burst
from tests.support.procs import wait_for
from tests.support.runs import wait_online

SPAN_S = 2.0  # each crossing lasts this long, from 0.1 s after the run started


def _crossing(t0: float, offset_y: float) -> tuple[list, list]:
    """a drives +x at 1 m/s, b drives -x on a line ``offset_y`` away; their x meet at t0 + 1. a is sampled at
    t0 + 0.0, 0.1, ..., b at t0 + 0.05, 0.15, ...: b's position at the meeting is interpolated."""
    a = [(k, t0 + k * 0.1, {"x": -1.0 + k * 0.1, "y": 0.0, "yaw": 0.0}) for k in range(21)]
    b = [(k, t0 + 0.05 + k * 0.1, {"x": 0.95 - k * 0.1, "y": offset_y, "yaw": 3.14}) for k in range(20)]
    return a, b


def _stored(c, robot: str, stream: str, n: int) -> bool:
    return any(s["stream"] == stream and s["count"] >= n for s in c.get(f"/api/robots/{robot}/streams").json())


def test_a_runs_summary_gives_the_closest_approach_and_counts_what_happened(server, mqtt_probe):
    robots = {rid: ProbeRobot(mqtt_probe, rid, sensors=("position", "avoidance")) for rid in ("sa", "sb", "sc", "sd")}
    for robot in robots.values():
        robot.status()
    with server.client() as c:
        wait_online(c, list(robots))
        close = c.post("/api/runs", json={"name": "crossing close", "robots": ["sa", "sb"]}).json()
        far = c.post("/api/runs", json={"name": "crossing far", "robots": ["sc", "sd"]}).json()
        # both runs cover the crossings' stretch once it has passed (stored rows are read by time range)
        time.sleep(max(0.0, close["started_at"] + SPAN_S + 0.3 - time.time()))
        for run in (close, far):
            assert c.post(f"/api/runs/{run['id']}/stop").status_code == 200
        t1 = close["started_at"] + 0.1
        a, b = _crossing(t1, 0.15)
        publish_burst(robots["sa"], "position", a)
        publish_burst(robots["sb"], "position", b)
        avoidance = [
            (0, t1 + 0.8, {"event": "active", "cause": "barrier", "neighbour": "sb", "distance_m": 0.25}),
            (1, t1 + 0.9, {"event": "active", "neighbour": "sb", "distance_m": 0.16, "duration_s": 0.1}),
            (2, t1 + 1.2, {"event": "cleared", "neighbour": "sb", "duration_s": 0.4}),
        ]
        publish_burst(robots["sa"], "avoidance", avoidance)
        t2 = far["started_at"] + 0.1
        c_, d_ = _crossing(t2, 0.5)
        publish_burst(robots["sc"], "position", c_)
        publish_burst(robots["sd"], "position", d_)
        wait_for(
            lambda: all(_stored(c, r, "position", 20) for r in robots) and _stored(c, "sa", "avoidance", 3),
            15,
            what="every sample stored",
        )

        # the close crossing: 0.15 m apart at t1 + 1, where only sa was sampled (the nearest samples of sb
        # would say 0.18 m); one violation of the site's 0.3 m and one contact (bodies of 0.1 m radius)
        sep = c.get(f"/api/runs/{close['id']}").json()["summary"]["separation"]
        assert sep["min_separation_m"] == pytest.approx(0.3) and sep["contact_m"] == pytest.approx(0.2)
        assert sep["closest"]["robots"] == ["sa", "sb"]
        assert sep["closest"]["distance_m"] == pytest.approx(0.15, abs=1e-6)
        assert sep["closest"]["ts"] == pytest.approx(t1 + 1.0, abs=1e-6)
        assert (sep["violations"], sep["contacts"]) == (1, 1)
        assert sep["violation_s"] == pytest.approx((0.3**2 - 0.15**2) ** 0.5, abs=0.01)
        assert sep["contact_s"] == pytest.approx((0.2**2 - 0.15**2) ** 0.5, abs=0.01)
        assert sep["samples"] == {"sa": 21, "sb": 20} and sep["pairs"][0]["samples"] == 39
        assert sep["interventions"] == 1 and sep["intervention_s"] == pytest.approx(0.4, abs=1e-6)
        assert sep["intervention_min_distance_m"] == pytest.approx(0.16)
        assert sep["interventions_by_robot"]["sb"]["count"] == 0

        # the far crossing: measured all along (the same counter counted above), nothing to count
        sep = c.get(f"/api/runs/{far['id']}").json()["summary"]["separation"]
        assert sep["pairs"][0]["samples"] == 39
        assert sep["closest"]["distance_m"] == pytest.approx(0.5, abs=1e-6)
        assert (sep["violations"], sep["violation_s"], sep["contacts"], sep["contact_s"]) == (0, 0.0, 0, 0.0)
        assert (sep["interventions"], sep["intervention_s"], sep["intervention_min_distance_m"]) == (0, 0.0, None)
