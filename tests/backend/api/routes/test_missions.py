"""``/api/missions`` with a real server, broker and simulated agent: every bad input gets a clear 422 with its
code, a robot that is not ready is refused with the reason, and a restart pauses a running mission with the
reason, keeping its history; Resume carries on and completes it."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
from shapely.geometry import box, shape
from sqlalchemy import create_engine, insert, select

from backend.models import MissionRow
from backend.services.missions.state import Coverage, built_coverage, rings
from fleet_protocol import Topics
from tests.support.missions import lawn_track, publish_site, wait_ready, wait_state
from tests.support.motion import first_stop_after, j, moving_at
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker, ServerProcess, wait_for

T = Topics()

Spawn = Callable[..., AgentProcess]
SQUARE = [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]


def coverage(robots: list[str], **params: object) -> dict[str, object]:
    return {"type": "coverage", "robots": robots, "params": {"area": SQUARE, "sweep_width_m": 0.25, **params}}


def refused(c: httpx.Client, body: object, code: str) -> str:
    """POST the mission: a 422 with ``code``; returns the field it names (a schema error's ``loc`` joined, or
    a service refusal's prefix, e.g. ``params.area``)."""
    r = c.post("/api/missions", json=body)
    assert r.status_code == 422, r.text
    assert r.json()["code"] == code, r.text
    detail = r.json()["detail"]
    if isinstance(detail, list):
        return ",".join(".".join(str(p) for p in e["loc"]) for e in detail)
    assert isinstance(detail, str) and ": " in detail, detail
    return detail.split(": ", 1)[0]


def test_bad_missions_get_a_clear_422(server: ServerProcess, spawn_agent: Spawn) -> None:
    """Every bad input of the issue's acceptance, one at a time: a 422 whose code says what and whose detail
    names the field."""
    spawn_agent("b1")
    with server.client() as c:
        wait_ready(c, ["b1"])
        # the same robot and area are fine: what follows is refused for the one thing changed
        ok = c.post("/api/missions", json=coverage(["b1"]))
        assert ok.status_code == 201, ok.text
        assert ok.json()["parts"][0]["path"]
        assert refused(c, coverage([]), "validation_error").endswith("robots")  # zero robots
        assert refused(c, coverage(["b1"], sweep_width_m=0), "validation_error").endswith("params.sweep_width_m")
        assert refused(c, coverage(["b1"], sweep_width_m=-0.2), "validation_error").endswith("sweep_width_m")
        r = c.post("/api/missions", json=coverage(["b1", "ghost"]))
        assert (r.status_code, r.json()["code"]) == (422, "unknown_robot"), r.text
        assert r.json()["detail"] == "robots: unknown robots: ghost"
        bowtie = [[-0.5, -0.5], [0.5, 0.5], [0.5, -0.5], [-0.5, 0.5]]  # self-intersecting
        assert refused(c, coverage(["b1"], area=bowtie), "bad_area") == "params.area"
        outside = [[1.5, 1.5], [3.0, 1.5], [3.0, 3.0], [1.5, 3.0]]
        assert refused(c, coverage(["b1"], area=outside), "area_outside_site") == "params.area"
        straddling = [[1.0, -0.5], [2.5, -0.5], [2.5, 0.5], [1.0, 0.5]]  # partly outside the 4 m pool
        assert refused(c, coverage(["b1"], area=straddling), "area_outside_site") == "params.area"
        assert refused(c, {"type": "coverage", "robots": ["b1", "b1"], "params": {}}, "validation_error").endswith(
            "robots"
        )
        body = {"type": "waypoints", "robots": ["b1"], "params": {"paths": {"x": [[0, 0]]}}}
        assert refused(c, body, "paths_mismatch") == "params.paths"
        # a waypoints mission names its robots too: an unknown one is refused the same way
        body = {"type": "waypoints", "robots": ["nobody"], "params": {"paths": {"nobody": [[0, 0]]}}}
        assert refused(c, body, "unknown_robot") == "robots"
        assert c.get("/api/missions").json() == [
            {k: v for k, v in ok.json().items() if k in c.get("/api/missions").json()[0]}
        ], "nothing refused was stored"
        # a mission's states: an unknown one is 404, a wrong action 409
        assert c.post("/api/missions/nosuch/start").json()["code"] == "unknown_mission"
        mid = ok.json()["id"]
        r = c.post(f"/api/missions/{mid}/resume")
        assert (r.status_code, r.json()["code"]) == (409, "bad_mission_state")


def test_a_robot_not_ready_is_refused_with_the_reason(
    server: ServerProcess, spawn_agent: Spawn, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    publish_site(mqtt_probe())
    agent = spawn_agent("n1")
    with server.client() as c:
        wait_ready(c, ["n1"])
        mid = c.post("/api/missions", json=coverage(["n1"])).json()["id"]
        agent.stop()  # offline: not ready
        deadline = time.time() + 15
        while c.get("/api/robots/n1").json()["online"] and time.time() < deadline:
            time.sleep(0.2)
        r = c.post(f"/api/missions/{mid}/start")
        assert r.status_code == 422, r.text
        assert r.json()["code"] == "robot_not_ready" and "n1: offline" in r.json()["detail"]
        assert c.get(f"/api/missions/{mid}").json()["state"] == "draft"


@pytest.mark.slow
def test_a_restart_pauses_a_running_mission_and_resume_completes_it(
    broker: Broker, database_url: str, workdir: Path, spawn_agent: Spawn, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    """The server is killed with -9 mid-mission: the robot stops within 1.5 s (its own motion reports: the
    first zero wheel set-point after the kill; it was driving when the server died), on its own (the goal ends
    ``unsupervised``: no server heartbeat). After a restart the mission is paused with the reason, nothing of
    its history is gone, and Resume completes it."""
    publish_site(mqtt_probe())
    motion = mqtt_probe(T.telemetry("s1", "motion"), T.ack("s1"))
    spawn_agent("s1", "--disturbances", "--start-pose=-0.4,-0.4,1.57")
    first = ServerProcess(broker, database_url, workdir)
    first.start()
    try:
        with first.client() as c:
            wait_ready(c, ["s1"])
            mid = c.post("/api/missions", json=coverage(["s1"])).json()["id"]
            assert c.post(f"/api/missions/{mid}/start").status_code == 200
            deadline = time.time() + 60
            while c.get(f"/api/missions/{mid}").json()["progress"][0]["waypoint_index"] < 2:
                m = c.get(f"/api/missions/{mid}").json()
                assert time.time() < deadline and m["state"] == "running", (m["reason"], m["events"], m["progress"])
                time.sleep(0.5)
            # its row commits (saved on every waypoint passed and every 2 s, by the writer thread), then it dies
            saved = wait_for(lambda: _stored_past(database_url, mid, 2), 10, interval=0.3, what="progress stored")
            before = c.get(f"/api/missions/{mid}").json()  # transitions and events as stored
            assert before["progress"][0]["status"] == "moving", before["progress"]
            killed = time.time()
    finally:
        first.kill()  # kill -9: no goodbye, no stop sent
    reports = wait_for(lambda: _stopped_since(motion, "s1", killed), 10, what="s1 stopped after the kill")
    assert moving_at(reports, killed), "s1 was not driving when the server died: the test proves nothing"
    stop = first_stop_after(reports, killed)
    assert stop is not None
    print(f"server killed: s1 stopped {stop - killed:.3f} s later (its motion reports)")
    assert stop - killed <= 1.5, stop - killed
    failed = [j(a) for a in motion.matching(lambda a: a.topic == T.ack("s1")) if j(a)["status"] == "failed"]
    assert failed and failed[-1]["reason"].startswith("unsupervised"), failed
    second = ServerProcess(broker, database_url, workdir)
    second.start()
    try:
        with second.client() as c:
            m = c.get(f"/api/missions/{mid}").json()
            assert m["state"] == "paused" and "server restarted" in m["reason"], m
            assert [t["to_state"] for t in m["transitions"]] == ["draft", "running", "paused"]
            assert m["transitions"][:2] == before["transitions"]  # times, actors and reasons as they were
            assert m["transitions"][-1]["actor"] == "system"
            assert all(e in m["events"] for e in before["events"])
            robot = saved["robots"][0]
            assert m["progress"][0]["waypoint_index"] >= max(robot["index"], robot["reached"]) >= 2
            assert m["covered_fraction"] >= round(saved["covered_fraction"], 4) > 0  # the track stored before the kill
            # a paused mission holds no lease: the dead process's is gone (not left to lapse), anyone may drive
            r = c.post("/api/robots/s1/lease")
            assert r.status_code == 200, r.text
            assert c.delete("/api/robots/s1/lease").status_code == 204
            wait_ready(c, ["s1"])
            r = c.post(f"/api/missions/{mid}/resume")
            assert r.status_code == 200, r.text
            done = wait_state(c, mid, ("completed", "failed", "paused"), timeout=120)
            assert done["state"] == "completed", (
                done["reason"],
                done["events"],
                done["progress"],
                second.output()[-3000:],
            )
            assert [t["to_state"] for t in done["transitions"]] == [
                "draft",
                "running",
                "paused",
                "running",
                "completed",
            ]
            assert done["covered_fraction"] >= 0.9
    finally:
        second.stop()


def _stored_past(database_url: str, mission_id: str, index: int) -> dict[str, Any] | None:
    """The mission's progress as its database row holds it (what a restart loads), once the robot's stored
    waypoint is past ``index``."""
    engine = create_engine(database_url)
    try:
        with engine.connect() as conn:
            progress = conn.execute(select(MissionRow.progress).where(MissionRow.id == mission_id)).scalar_one()
    finally:
        engine.dispose()
    robots = progress.get("robots") or [{}]
    return progress if max(robots[0].get("index", 0), robots[0].get("reached", 0)) >= index else None


def _stopped_since(probe: MqttProbe, rid: str, t: float) -> list[dict[str, Any]] | None:
    topic = T.telemetry(rid, "motion")
    reports = [j(m) for m in probe.matching(lambda m: m.topic == topic)]
    return reports if first_stop_after(reports, t) is not None else None


def test_the_swept_area_of_a_long_mission_is_outlined_on_the_planner_pool(server: ServerProcess) -> None:
    """Issue 28: ``GET /coverage`` read the swept area that every step and every mirrored row rebuilt on the
    event loop from the whole tracks. Another replica's mission, three robots with 12,000 points each (an
    hour's sweep), appears in the database: this server mirrors it with the figure its owner stored, and its
    swept area (GeoJSON and PNG) is built, outlined and drawn on the planner pool, whose job count says so;
    the outline's area is the covered fraction's. Asked again unchanged, the outline is not drawn again."""
    region = box(-1.75, -1.75, 1.75, 1.75)
    # each robot sweeps its third of the pool 18 times over, lanes 0.3 m apart (gaps between the strips)
    tracks = [
        [p for n in range(18) for p in lawn_track(x, x + 1.15, -1.7, 1.7, 0.3, seed=10 * i + n)]
        for i, x in enumerate((-1.7, -0.55, 0.6))
    ]
    assert min(len(t) for t in tracks) >= 12_000
    # the figure its owner stored (the union of these tracks' buffers, as a step made it before: 31 s of CPU)
    owners = built_coverage(Coverage(rings(region), [], 0.2), [(f"r{i}", t, len(t)) for i, t in enumerate(tracks)])
    assert 0.5 < owners.fraction < 0.95
    robots = [
        {"robot_id": f"r{i}", "path": [[0.0, 0.0]], "breaks": [1], "track": t, "status": "moving"}
        for i, t in enumerate(tracks)
    ]
    now = time.time()
    row = {
        "id": "long1",
        "name": "an hour's sweep",
        "type": "coverage",
        "state": "running",
        "reason": "",
        "robots": ["r0", "r1", "r2"],
        "params": {"sweep_width_m": 0.2, "overlap": 0.0},
        "plan": {"workable": [[list(c) for c in region.exterior.coords]], "holes": [], "workable_area_m2": 12.25},
        "progress": {"robots": robots, "covered_fraction": owners.fraction, "swept_m2": owners.per_robot},
        "created_by": "op",
        "created_at": now,
        "updated_at": now,
        "started_at": now,
        "owner": "another-replica",
        "heartbeat_at": now + 3600,  # alive: mirrored, not taken over
    }
    engine = create_engine(server.database_url)
    with engine.begin() as conn:
        conn.execute(insert(MissionRow).values(**row))
    engine.dispose()
    with server.client() as c:
        wait_for(lambda: c.get("/api/missions/long1").status_code == 200, 15, what="the row mirrored")
        mirrored = c.get("/api/missions/long1").json()
        assert (mirrored["state"], mirrored["replica"]) == ("running", "another-replica")
        assert mirrored["covered_fraction"] == round(owners.fraction, 4)  # its owner's figure: nothing built here
        jobs = c.get("/api/stats").json()["pools"]["planner"]["done"]
        r = c.get("/api/missions/long1/coverage")
        assert r.status_code == 200 and r.headers["content-type"] == "application/geo+json", r.text
        outlined = c.get("/api/stats").json()["pools"]["planner"]["done"]
        assert outlined >= jobs + 2, (jobs, outlined)  # its grid built, then outlined: both on the pool
        swept = shape(r.json())
        shown = c.get("/api/missions/long1").json()
        assert swept.area == pytest.approx(shown["covered_fraction"] * 12.25, rel=0.005)
        assert shown["covered_fraction"] == pytest.approx(owners.fraction, abs=1e-4)  # its own grid now, the same
        assert c.get("/api/missions/long1/coverage").content == r.content
        assert c.get("/api/stats").json()["pools"]["planner"]["done"] == outlined  # unchanged: not drawn again
        png = c.get("/api/missions/long1/coverage", params={"format": "png", "px_per_m": 50})
        assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
        assert c.get("/api/stats").json()["pools"]["planner"]["done"] == outlined + 1
