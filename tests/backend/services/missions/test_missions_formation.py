"""The ``formation`` mission with real parts: Mosquitto, the server, three simulated agents with every
disturbance on. The server runs the formation law (fleet_common/formation.py, the same code as
examples/formation.py) on the robots' live positions; the slot error is measured from the STORED positions.
Bad formation missions get a clear 422 naming the field."""

from __future__ import annotations

import itertools
import math
import statistics
import time
from collections.abc import Callable
from typing import Any

import httpx
import pytest

from examples.formation import LEFT_SLOT, RIGHT_SLOT, circle_path
from tests.support.formation import formation_errors
from tests.support.missions import min_pairwise_distance, publish_site, wait_ready, wait_state
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, ServerProcess, wait_for

Spawn = Callable[..., AgentProcess]
RADIUS = 0.7
SECONDS = 24.0
SETTLE_S = 6.0  # as in tests/examples/test_formation.py: the leader first turns onto its path
ROBOTS = ["fm-lead", "fm-left", "fm-right"]
SLOTS = {"fm-left": LEFT_SLOT, "fm-right": RIGHT_SLOT}


def formation(**params: Any) -> dict[str, Any]:
    body: dict[str, Any] = {
        "leader": "fm-lead",
        "path": circle_path(RADIUS),
        "slots": {rid: list(s) for rid, s in SLOTS.items()},
        "duration_s": SECONDS,
    }
    body.update(params)
    return {"type": "formation", "name": "ci formation", "robots": ROBOTS, "params": body}


def refused(c: httpx.Client, body: dict[str, Any], code: str) -> str:
    r = c.post("/api/missions", json=body)
    assert r.status_code == 422, r.text
    assert r.json()["code"] == code, r.text
    return str(r.json()["detail"])


def stored(c: httpx.Client, robot_id: str, start: float, end: float) -> tuple[list[float], list[dict[str, Any]]]:
    r = c.get(
        f"/api/robots/{robot_id}/telemetry",
        params={"stream": "position", "start": start, "end": end, "raw": "true", "limit": 10000},
    )
    assert r.status_code == 200, r.text
    points = r.json()["points"]
    return [p["ts"] for p in points], [p["data"] for p in points]


def _xy(ts: list[float], data: list[dict[str, Any]]) -> list[tuple[float, float, float]]:
    return [(t, d["x"], d["y"]) for t, d in zip(ts, data, strict=True)]


@pytest.mark.slow
def test_the_server_holds_a_formation_around_a_path_following_leader(
    server: ServerProcess, spawn_agent: Spawn, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    publish_site(mqtt_probe())
    starts = {"fm-lead": (RADIUS, 0.0)} | {rid: (RADIUS - s[1], s[0]) for rid, s in SLOTS.items()}
    for rid, (x, y) in starts.items():
        spawn_agent(rid, "--disturbances", f"--start-pose={x},{y},{math.pi / 2}")
    with server.client() as c:
        wait_ready(c, ROBOTS)
        # bad input: each refused for the one thing changed, nothing created
        before = len(c.get("/api/missions").json())
        assert "leader" in refused(c, formation(leader="nobody"), "leader_not_in_mission")
        assert "slots" in refused(c, formation(slots={"fm-left": [-0.35, 0.3]}), "slots_mismatch")
        assert "slots" in refused(
            c, formation(slots={"fm-left": [-0.35, 0.3], "fm-right": [-0.3, 0.2]}), "slots_too_close"
        )
        assert "path" in refused(c, formation(path=[[0.0, 0.0], [2.5, 0.0]]), "outside_site")
        assert "slots" in refused(
            c, formation(slots={"fm-left": [-0.35, 30.0], "fm-right": [-0.35, -0.3]}), "validation_error"
        )
        assert "speed" in refused(c, formation(speed=0.5), "validation_error")
        assert "speed" in refused(c, formation(speed=0), "validation_error")
        assert "path" in refused(c, formation(path=[[0.0, 0.0]]), "validation_error")
        assert "duration_s" in refused(c, formation(duration_s=-1), "validation_error")
        assert len(c.get("/api/missions").json()) == before

        r = c.post("/api/missions", json=formation())
        assert r.status_code == 201, r.text
        mid = r.json()["id"]
        r = c.post(f"/api/missions/{mid}/start")
        assert r.status_code == 200, r.text
        t0 = time.time()
        done = wait_state(c, mid, ("completed", "failed", "paused", "aborted"), timeout=SECONDS + 30)
        t1 = done["ended_at"]
        assert done["state"] == "completed", (done["reason"], done["progress"], done["events"])
        assert [(t["from_state"], t["to_state"]) for t in done["transitions"]] == [
            ("", "draft"),
            ("draft", "running"),
            ("running", "completed"),
        ]
        # every robot's fixes up to the end are stored once one stamped after it is (the writer keeps order)
        wait_for(lambda: all(stored(c, rid, t1, t1 + 60)[0] for rid in ROBOTS), 15, what="fixes past the end stored")
        lead_ts, lead = stored(c, "fm-lead", t0 + SETTLE_S, t1)
        tracks = {rid: stored(c, rid, t0 + SETTLE_S, t1) for rid in SLOTS}
        whole = {rid: stored(c, rid, t0, t1) for rid in ROBOTS}
    travelled = sum(math.dist((a["x"], a["y"]), (b["x"], b["y"])) for a, b in itertools.pairwise(lead[::10]))
    assert travelled > 0.5, f"the leader hardly moved ({travelled:.2f} m): nothing was tested"
    measured = formation_errors(lead_ts, lead, tracks, SLOTS)
    for rid in SLOTS:
        assert len(measured.slot[rid]) > 10 * (SECONDS - SETTLE_S - 2), f"{rid}: too few stored fixes matched"
        mean, p95, worst = measured.summary(rid)
        print(f"{rid}: slot error mean {mean * 100:.1f} cm, p95 {p95 * 100:.1f} cm, max {worst * 100:.1f} cm")
        assert mean <= 0.05, f"{rid}: mean distance from its slot {mean:.3f} m"
        assert worst <= 0.15, f"{rid}: worst distance from its slot {worst:.3f} m"
    print(f"triangle sides: mean error {statistics.fmean(measured.sides) * 100:.1f} cm")
    closest = min_pairwise_distance({rid: _xy(*track) for rid, track in whole.items()})
    print(f"closest two robots came {closest:.3f} m (stored positions, whole run)")
    assert closest >= 0.3, closest
