"""Experiment runs over real processes (broker, server, simulated agents): start, markers, summary, stop,
search, edit, delete (admin, audited), the audit of starting, editing and stopping, and the errors for bad
input."""

from __future__ import annotations

import itertools
import math
import time

from tests.backend.helpers import ProbeRobot, audit_trail, operator_token, wait_robot
from tests.support.procs import ServerProcess, wait_for
from tests.support.runs import raw_rows, wait_online, wait_stored_past


def test_a_run_records_its_robots_and_summarises_them(server, spawn_agent):
    spawn_agent("run-a", "--start-pose=0,0,0")
    spawn_agent("run-b", "--start-pose=1,0,0")
    spawn_agent("run-out", "--start-pose=-1,0,0")  # online but not in the run
    with server.client() as c:
        wait_online(c, ["run-a", "run-b", "run-out"])
        r = c.post(
            "/api/runs", json={"name": "trial 7", "tags": ["current-on", "3 robots"], "robots": ["run-a", "run-b"]}
        )
        assert r.status_code == 201, r.text
        run = r.json()
        assert run["running"] and run["ended_at"] is None and run["robots"] == ["run-a", "run-b"]
        assert run["operator"] and run["site_version"] >= 1
        assert run["site_version"] == c.get("/api/site").json()["version"]
        assert set(run["agents"]) == {"run-a", "run-b"}
        assert (
            run["agents"]["run-a"]["agent_version"] and "position" in run["agents"]["run-a"]["capabilities"]["sensors"]
        )
        rid = run["id"]

        # a drive during the run: the robot moves, the command is counted
        r = c.post(
            "/api/robots/run-a/commands", json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 1.5}}
        )
        assert r.status_code == 202, r.text
        time.sleep(3.0)
        m = c.post(f"/api/runs/{rid}/markers", json={"text": "tag 3 fell", "robot_id": "run-b"})
        assert m.status_code == 201, m.text
        assert m.json()["robot_id"] == "run-b" and m.json()["run_id"] == rid
        time.sleep(0.5)
        stopped = c.post(f"/api/runs/{rid}/stop")
        assert stopped.status_code == 200, stopped.text
        run = stopped.json()
        assert not run["running"] and run["ended_at"] > run["started_at"]
        again = c.post(f"/api/runs/{rid}/stop")
        assert again.status_code == 409 and again.json()["code"] == "run_ended"
        wait_stored_past(c, ["run-a", "run-b"], run["ended_at"])  # the summary and the rows read the same

        detail = c.get(f"/api/runs/{rid}").json()
        summary = detail["summary"]
        assert abs(summary["duration_s"] - (run["ended_at"] - run["started_at"])) < 1e-6
        assert [mk["text"] for mk in detail["markers"]] == ["tag 3 fell"]
        counts = {(s["robot_id"], s["stream"]): s["count"] for s in summary["messages"]}
        assert not any(robot == "run-out" for robot, _ in counts)  # only the run's robots
        for robot in ("run-a", "run-b"):
            rows = raw_rows(c, robot, "position", run["started_at"], run["ended_at"])
            assert len(rows) > 20
            assert counts[(robot, "position")] == len(rows)
            expected = sum(
                math.hypot(b["data"]["x"] - a["data"]["x"], b["data"]["y"] - a["data"]["y"])
                for a, b in itertools.pairwise(rows)
            )
            assert abs(summary["distance_m"][robot] - expected) < 1e-3
        assert summary["distance_m"]["run-a"] > 0.2  # it drove: the measure can tell a moved robot
        assert summary["messages_total"] == sum(counts.values())
        assert summary["commands"] >= 1 and summary["estops"] == 0
        assert summary["gaps_missing"] == 0 and summary["gaps"] == []

        # the marker shows in the event list too
        events = c.get("/api/events", params={"kind": "marker"}).json()
        assert any(e["detail"].get("text") == "tag 3 fell" for e in events)


def test_runs_are_found_by_name_tag_and_robot_and_edited(server, spawn_agent):
    spawn_agent("find-a")
    spawn_agent("find-b")
    with server.client() as c:
        wait_online(c, ["find-a", "find-b"])
        a = c.post("/api/runs", json={"name": "Current sweep", "tags": ["current"], "robots": ["find-a"]}).json()
        b = c.post(
            "/api/runs", json={"name": "calm water 50%", "tags": ["calm", "50%_flow"], "robots": ["find-b"]}
        ).json()
        c.post(f"/api/runs/{a['id']}/stop")

        def ids(**params: object) -> list[int]:
            r = c.get("/api/runs", params=params)
            assert r.status_code == 200, r.text
            return [x["id"] for x in r.json()]

        assert ids() == [b["id"], a["id"]]  # newest first
        assert ids(name="sweep") == [a["id"]]  # any case, part of the name
        assert ids(name="50%") == [b["id"]]  # % is a character, not a wildcard
        assert ids(name="5_%") == []
        assert ids(tag="calm") == [b["id"]] and ids(tag="cal") == []  # whole tags only
        assert ids(tag="50%_flow") == [b["id"]] and ids(tag="50%") == [] and ids(tag="5__flow") == []
        assert ids(robot="find-a") == [a["id"]] and ids(robot="find") == []
        assert ids(running="true") == [b["id"]] and ids(running="false") == [a["id"]]
        assert ids(before_id=b["id"]) == [a["id"]]

        r = c.patch(f"/api/runs/{a['id']}", json={"notes": "pump at 40 %", "tags": ["current", "pump"]})
        assert r.status_code == 200 and r.json()["notes"] == "pump at 40 %"
        assert ids(tag="pump") == [a["id"]]
        assert c.get(f"/api/runs/{a['id']}").json()["tags"] == ["current", "pump"]


def test_bad_input_gets_clear_errors(server, spawn_agent):
    with server.client() as c:
        assert c.get("/api/runs/999").json()["code"] == "unknown_run"
        assert c.post("/api/runs/999/stop").status_code == 404
        assert c.post("/api/runs/999/markers", json={"text": "x"}).json()["code"] == "unknown_run"
        assert c.get("/api/runs/999/export").status_code == 404
        r = c.post("/api/runs", json={"name": "nobody", "robots": ["ghost"]})
        assert r.status_code == 404 and r.json()["code"] == "unknown_robot"
        # no robot named and none online yet: refused, not an empty run (asked before any robot is started: a
        # robot started first could be online by now, and was once its start got faster)
        r = c.post("/api/runs", json={"name": "empty"})
        assert r.status_code == 409 and r.json()["code"] == "no_robots"
        spawn_agent("bad-a")
        wait_online(c, ["bad-a"])
        run = c.post("/api/runs", json={"name": "all online"}).json()
        assert run["robots"] == ["bad-a"]
        rid = run["id"]
        early = c.post(f"/api/runs/{rid}/markers", json={"text": "before", "ts": run["started_at"] - 10})
        assert early.status_code == 409 and early.json()["code"] == "marker_outside_run"
        late = c.post(f"/api/runs/{rid}/markers", json={"text": "future", "ts": time.time() + 3600})
        assert late.status_code == 409 and late.json()["code"] == "marker_outside_run"
        other = c.post(f"/api/runs/{rid}/markers", json={"text": "x", "robot_id": "ghost"})
        assert other.status_code == 409 and other.json()["code"] == "robot_not_in_run"
        assert c.post("/api/runs", json={"name": ""}).status_code == 422
        assert c.post("/api/runs", json={"name": "x", "tags": ["a|b"]}).status_code == 422
        assert c.post("/api/runs", json={"name": "x", "robots": []}).status_code == 422  # an empty run: no
        assert c.post("/api/runs", json={"name": "x", "frame_rate": False}).status_code == 422
        assert c.post("/api/runs", json={"name": "x", "frame_rate": 61}).status_code == 422
        # nothing was lost: the good marker goes in, the bad ones left no trace
        ok = c.post(f"/api/runs/{rid}/markers", json={"text": "fine", "ts": run["started_at"] + 0.001})
        assert ok.status_code == 201
        stopped = c.post(f"/api/runs/{rid}/stop").json()
        after = c.post(f"/api/runs/{rid}/markers", json={"text": "after", "ts": stopped["ended_at"] + 1})
        assert after.status_code == 409 and after.json()["code"] == "marker_outside_run"
        assert [m["text"] for m in c.get(f"/api/runs/{rid}/markers").json()] == ["fine"]


def test_deleting_a_run_is_for_admins_and_audited(server, spawn_agent):
    spawn_agent("del-a")
    with server.client() as c:
        wait_online(c, ["del-a"])
        rid = c.post("/api/runs", json={"name": "to delete", "robots": ["del-a"]}).json()["id"]
        c.post(f"/api/runs/{rid}/stop")
        token = c.post("/api/tokens", json={"name": "op", "role": "operator"}).json()["token"]
    with server.client(token) as op:
        r = op.delete(f"/api/runs/{rid}")
        assert r.status_code == 403
        assert op.get(f"/api/runs/{rid}").status_code == 200
        # an operator may start and stop runs and set markers
        rid2 = op.post("/api/runs", json={"name": "op run", "robots": ["del-a"]}).json()["id"]
        assert op.post(f"/api/runs/{rid2}/markers", json={"text": "ok"}).status_code == 201
    with server.client() as c:
        assert c.delete(f"/api/runs/{rid}").status_code == 204
        assert c.get(f"/api/runs/{rid}").status_code == 404
        assert c.delete(f"/api/runs/{rid}").status_code == 404
        entries = wait_for(lambda: c.get("/api/audit", params={"action": "run_delete"}).json(), 5, what="audit")
        assert entries[0]["detail"]["run_id"] == rid and entries[0]["detail"]["name"] == "to delete"
        assert [r["id"] for r in c.get("/api/runs").json()] == [rid2]


def test_a_run_survives_a_server_killed_mid_run(broker, database_url, workdir, spawn_agent):
    server = ServerProcess(broker, database_url, workdir)
    server.start()
    try:
        spawn_agent("kill-a")
        with server.client() as c:
            wait_online(c, ["kill-a"])
            run = c.post("/api/runs", json={"name": "crash", "robots": ["kill-a"]}).json()
            c.post(f"/api/runs/{run['id']}/markers", json={"text": "before the crash"})
            time.sleep(2.0)
            before = c.get(f"/api/runs/{run['id']}").json()["summary"]["messages_total"]
            assert before > 0
        server.kill()
        server.start()
        with server.client() as c:
            detail = c.get(f"/api/runs/{run['id']}").json()
            assert detail["running"] and [m["text"] for m in detail["markers"]] == ["before the crash"]
            assert detail["summary"]["messages_total"] >= before  # nothing already stored was lost
            stopped = c.post(f"/api/runs/{run['id']}/stop")
            assert stopped.status_code == 200 and not stopped.json()["running"]
    finally:
        server.stop()


def test_starting_editing_and_stopping_a_run_is_audited(server, mqtt_probe):
    """Issue 29 #6: who started, renamed, re-tagged and stopped a run is in the audit trail, as deleting it was."""
    ProbeRobot(mqtt_probe, "aud-r").status()
    token, _ = operator_token(server, "olga")
    with server.client(token) as op:
        wait_robot(op, "aud-r", lambda r: r["online"])
        started = op.post("/api/runs", json={"name": "pool test", "robots": ["aud-r"]})
        assert started.status_code == 201, started.text
        rid = started.json()["id"]
        assert op.patch(f"/api/runs/{rid}", json={"name": "pool test 2", "tags": ["calib"]}).status_code == 200
        assert op.post(f"/api/runs/{rid}/stop").status_code == 200
        token_id = op.get("/api/auth/me").json()["subject"].removeprefix("token:")

    def runs_audited() -> list[dict] | None:
        entries = [e for e in audit_trail(server) if e["action"].startswith("run_")]
        return entries if len(entries) >= 3 else None

    entries = wait_for(runs_audited, 5, what="the run's audit entries")
    assert [(e["action"], e["actor_name"], e["token_id"], e["detail"]) for e in entries] == [
        ("run_start", "olga", token_id, {"run_id": rid, "name": "pool test", "robots": ["aud-r"]}),
        ("run_update", "olga", token_id, {"run_id": rid, "was": "pool test", "name": "pool test 2", "tags": ["calib"]}),
        ("run_stop", "olga", token_id, {"run_id": rid, "name": "pool test 2"}),
    ]
