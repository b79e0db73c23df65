"""A 20-point path with every disturbance on: cross-track error measured from the robot's own position stream
against the polyline, mean <= 5 cm and max <= 15 cm; the agent reports its cross-track error too."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from fleet_protocol import default_pool_site
from tests.support.motion import DISTURBED, FakeServer, polyline_distance
from tests.support.procs import AgentProcess

Spawn = Callable[..., AgentProcess]


def twenty_points() -> list[list[float]]:
    """A closed-looking tour with straight stretches and corners of different sharpness (not a circle)."""
    pts = []
    for i in range(20):
        a = 2 * math.pi * i / 20
        r = 0.9 + 0.35 * math.cos(3 * a)
        pts.append([round(r * math.cos(a), 3), round(r * math.sin(a), 3)])
    return pts


@pytest.mark.slow
def test_twenty_point_path_cross_track(spawn_agent: Spawn, fake_server: FakeServer) -> None:
    srv = fake_server
    srv.publish_site(1, default_pool_site())
    srv.start_heartbeat()
    path = twenty_points()
    spawn_agent("p1", *DISTURBED, f"--start-pose={path[0][0]},{path[0][1]},1.6")
    srv.wait_online("p1")
    cid = srv.send("p1", "follow_path", {"waypoints": path, "tolerance_m": 0.05, "max_speed": 0.15})
    accepted = srv.ack("p1", cid, "accepted")
    final = srv.final_ack("p1", cid, timeout=150)
    assert final["status"] == "done", final
    fixes = [e["data"] for e in srv.stream("p1", "position") if accepted["ts"] <= e["ts"] <= final["ts"]]
    assert len(fixes) > 100
    errors = [polyline_distance((f["x"], f["y"]), path) for f in fixes]
    mean, worst = sum(errors) / len(errors), max(errors)
    print(
        f"20-point path: {len(fixes)} fixes, cross-track mean {mean * 100:.2f} cm, max {worst * 100:.2f} cm, "
        f"{final['ts'] - accepted['ts']:.1f} s"
    )
    assert mean <= 0.05 and worst <= 0.15, (mean, worst)
    reports = srv.motion("p1", cid)
    active = [e["data"] for e in reports if e["data"]["state"] == "active"]
    assert {d["waypoint_count"] for d in active} == {20}
    assert max(d["waypoint_index"] for d in active) == 19  # heading for each waypoint in turn, up to the last
    assert all(d["cross_track_m"] is not None and d["cross_track_m"] < 0.15 for d in active)
