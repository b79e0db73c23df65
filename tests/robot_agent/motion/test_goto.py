"""Go-to goals on a real agent with every simulator disturbance on: reached within 5 cm, acked with the site
version they were checked against, reported on the motion stream at 5 Hz or more."""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Callable

import orjson
import pytest

from fleet_protocol import MOTION_STREAM, decode_telemetry, default_pool_site
from tests.support.motion import DISTURBED, FakeServer
from tests.support.procs import AgentProcess

Spawn = Callable[..., AgentProcess]


@pytest.mark.slow
def test_random_goals_reached_within_5cm(spawn_agent: Spawn, fake_server: FakeServer) -> None:
    srv = fake_server
    srv.publish_site(3, default_pool_site())
    srv.start_heartbeat()
    spawn_agent("m1", *DISTURBED, "--start-pose=0,0,0")
    srv.wait_online("m1")
    rng = random.Random(17)
    for _ in range(3):
        gx, gy = rng.uniform(-1.7, 1.7), rng.uniform(-1.7, 1.7)
        cid = srv.send("m1", "goto", {"x": gx, "y": gy, "tolerance_m": 0.05})
        accepted = srv.ack("m1", cid, "accepted")
        assert "site v3" in accepted["reason"]
        final = srv.final_ack("m1", cid, timeout=90)
        assert final["status"] == "done", final
        reports = srv.motion("m1", cid)
        for e in reports:  # what the server validates the stream with
            decode_telemetry(orjson.dumps(e), MOTION_STREAM)
        end = reports[-1]
        assert end["data"]["state"] == "done" and end["data"]["site_version"] == 3
        # where the robot really was when it said done: the Lighthouse fixes around that moment
        fixes = [e["data"] for e in srv.stream("m1", "position") if abs(e["ts"] - end["ts"]) < 0.15]
        assert fixes
        err = sum(math.hypot(f["x"] - gx, f["y"] - gy) for f in fixes) / len(fixes)
        assert err <= 0.05, (gx, gy, err)
        # the motion stream runs at 5 Hz or more while the goal is active
        ts = [e["ts"] for e in reports]
        gaps = [b - a for a, b in itertools.pairwise(ts)]
        assert max(gaps) <= 0.2 + 0.05, max(gaps)
