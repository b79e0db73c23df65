"""A mission opens its own run when it starts (its robots, the site version, tag ``mission``) and the run ends
when the mission ends: completed, or aborted. Real server, broker and simulated agents."""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest

from tests.support.missions import publish_site, wait_ready, wait_state
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, ServerProcess, wait_for

PATHS = {"mr1": [[0.0, 0.0], [0.25, 0.0]], "mr2": [[0.0, 0.6], [0.25, 0.6]]}


def _start(c: httpx.Client, name: str) -> tuple[dict, dict]:
    body = {"type": "waypoints", "name": name, "robots": list(PATHS), "params": {"paths": PATHS}}
    created = c.post("/api/missions", json=body)
    assert created.status_code == 201, created.text
    assert created.json()["run_id"] is None  # a draft records nothing
    started = c.post(f"/api/missions/{created.json()['id']}/start")
    assert started.status_code == 200, started.text
    mission = started.json()
    assert mission["run_id"] is not None, mission
    run = c.get(f"/api/runs/{mission['run_id']}").json()
    assert run["mission_id"] == mission["id"], run  # and the run names its mission
    listed = {m["id"]: m for m in c.get("/api/missions").json()}[mission["id"]]
    assert listed["run_id"] == run["id"] and listed["started_at"] == mission["started_at"], listed
    return mission, run


def test_a_mission_records_its_own_run_until_it_ends(
    server: ServerProcess, spawn_agent: Callable[..., AgentProcess], mqtt_probe: Callable[..., MqttProbe]
) -> None:
    publish_site(mqtt_probe())
    spawn_agent("mr1", "--start-pose=0,0,0")
    spawn_agent("mr2", "--start-pose=0,0.6,0")
    spawn_agent("other", "--start-pose=-0.8,-0.8,0")
    with server.client() as c:
        wait_ready(c, [*PATHS, "other"])
        site_version = c.get("/api/site").json()["version"]
        # completed: the run holds the mission's robots only, and ends with it
        mission, run = _start(c, "short sweep")
        assert run["running"] and run["robots"] == sorted(PATHS) and run["tags"] == ["mission"]
        assert run["name"] == "mission short sweep" and mission["id"] in run["notes"]
        assert run["site_version"] == site_version
        done = wait_state(c, mission["id"], ("completed", "failed"), 60)
        assert done["state"] == "completed", done
        ended = wait_for(lambda: (r := c.get(f"/api/runs/{run['id']}").json())["ended_at"] and r, 10, what="run end")
        assert ended["ended_at"] >= done["ended_at"] - 0.5
        assert ended["summary"]["messages_total"] > 0  # it recorded the robots while they drove
        # its report: how close its robots came (0.6 m apart, side by side), measured from their stored
        # positions all along, and nothing under the safety distance; the run's summary measures the same
        sep = done["separation"]
        assert sep["min_separation_m"] == pytest.approx(0.3) and [p["robots"] for p in sep["pairs"]] == [["mr1", "mr2"]]
        assert sep["pairs"][0]["samples"] > 20 and 0.45 < sep["closest"]["distance_m"] < 0.75, sep
        assert (sep["violations"], sep["contacts"]) == (0, 0), sep
        assert done["started_at"] <= sep["closest"]["ts"] <= done["ended_at"] + 1.0
        assert ended["summary"]["separation"]["pairs"][0]["samples"] >= sep["pairs"][0]["samples"] - 5
        assert {e["kind"] for e in done["events"]} >= {"run_opened"}
        # aborted: the same
        mission, run = _start(c, "aborted sweep")
        assert run["running"]
        r = c.post(f"/api/missions/{mission['id']}/abort")
        assert r.status_code == 200, r.text
        wait_for(lambda: c.get(f"/api/runs/{run['id']}").json()["ended_at"], 10, what="the aborted mission's run end")
        # a run the operator stopped by hand first: the mission still ends cleanly
        mission, run = _start(c, "stopped by hand")
        assert c.post(f"/api/runs/{run['id']}/stop").status_code == 200
        assert c.post(f"/api/missions/{mission['id']}/abort").status_code == 200
        assert wait_state(c, mission["id"], ("aborted",), 10)["run_id"] == run["id"]
