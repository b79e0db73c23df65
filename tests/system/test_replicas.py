"""More than one server: two replicas, one PostgreSQL database, one Mosquitto, three simulated robots.

Ingest goes through the MQTT v5 shared subscription ``$share/<group>/fleet/+/telemetry/#`` (each message
to one replica), so every telemetry message is stored exactly once; each replica also subscribes
non-shared to status, acks, e-stop and live telemetry for its own WebSocket clients. A command sent
through replica A is acked to a REST client and a WebSocket client of replica B. A mission runs on one
replica; when that one dies, its robots stop and another replica takes the mission over, paused.
"""

from __future__ import annotations

import asyncio
import time

import orjson
import pytest
from sqlalchemy import create_engine, text

from fleet_protocol import Topics
from tests.backend.helpers import ws_collect
from tests.support.missions import publish_site, wait_ready, wait_state
from tests.support.motion import first_stop_after, moving_at
from tests.support.procs import replica_pair, wait_for

pytestmark = pytest.mark.postgres

ROBOTS = ("rep-1", "rep-2", "rep-3")
T = Topics()


def _duplicates_and_gaps(url: str) -> tuple[list[tuple[str, str, int, int]], dict[tuple[str, str], list[int]]]:
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            dups = [
                tuple(r)
                for r in conn.execute(
                    text(
                        "SELECT robot_id, stream, seq, count(*) FROM telemetry GROUP BY robot_id, stream, seq "
                        "HAVING count(*) <> 1"
                    )
                )
            ]
            seqs: dict[tuple[str, str], list[int]] = {}
            for robot_id, stream, seq in conn.execute(
                text("SELECT robot_id, stream, seq FROM telemetry ORDER BY robot_id, stream, seq")
            ):
                seqs.setdefault((robot_id, stream), []).append(int(seq))
    finally:
        engine.dispose()
    return dups, seqs  # type: ignore[return-value]


def _published_max(probe) -> dict[tuple[str, str], int]:  # type: ignore[no-untyped-def]
    top: dict[tuple[str, str], int] = {}
    for m in probe.matching(lambda m: "/telemetry/" in m.topic):
        parts = m.topic.split("/")
        top[(parts[1], parts[3])] = max(top.get((parts[1], parts[3]), -1), int(orjson.loads(m.payload)["seq"]))
    return top


def test_two_replicas_store_once_and_share_acks(broker, pg_url, workdir, spawn_agent, mqtt_probe):
    probe = mqtt_probe("fleet/+/telemetry/#")
    replicas = replica_pair(broker, pg_url, workdir)
    a, b = replicas
    a.start()  # the first replica migrates the schema; the second finds it at head
    b.start()
    try:
        agents = [spawn_agent(r, "--position-rate", "50") for r in ROBOTS]
        for s in replicas:
            with s.client() as c:
                wait_for(
                    lambda c=c: all(
                        c.get(f"/api/robots/{r}").status_code == 200 and c.get(f"/api/robots/{r}").json()["online"]
                        for r in ROBOTS
                    ),
                    20,
                    interval=0.2,
                    what="robots online on every replica",
                )
                mqtt = c.get("/api/stats").json()["mqtt"]
                assert mqtt["protocol"] == "5"

        # Live telemetry of every robot reaches a WebSocket client of replica B (its own subscription).
        async def _live_on_b() -> list[dict]:
            msgs, _ = await ws_collect(
                b.ws_url,
                {"type": "subscribe", "robots": ["*"], "streams": ["position"]},
                lambda ms: {m["robot_id"] for m in ms if m["type"] == "telemetry"} >= set(ROBOTS),
                timeout=15,
            )
            return msgs

        asyncio.run(_live_on_b())

        # A command through replica A: acked to B's WebSocket client and visible through B's REST.
        sent: dict[str, dict] = {}

        def _send_via_a() -> None:
            with a.client() as c:
                r = c.post(f"/api/robots/{ROBOTS[0]}/commands?wait=5", json={"command": "stop", "source": "test"})
                assert r.status_code == 200, r.text
                sent["cmd"] = r.json()

        def _acked_on_b(ms: list[dict]) -> bool:
            cmd = sent.get("cmd")
            return cmd is not None and any(
                m["type"] == "command" and m["command"]["id"] == cmd["id"] and m["command"]["status"] == "done"
                for m in ms
            )

        msgs, _ = asyncio.run(
            ws_collect(
                b.ws_url,
                {"type": "subscribe", "robots": [ROBOTS[0]], "streams": []},
                _acked_on_b,
                timeout=15,
                on_open=_send_via_a,
            )
        )
        cmd = sent["cmd"]
        assert cmd["status"] == "done"
        on_b = [m["command"] for m in msgs if m["type"] == "command" and m["command"]["id"] == cmd["id"]]
        assert on_b[-1]["acks"][-1]["status"] == "done"
        with b.client() as c:
            # A publishes before its commit, so B may store an ack only on a retry, after A's own ack updates:
            # eventually both acks, each stored once (not once per replica), whatever the order of arrival
            expected = [ack["status"] for ack in cmd["acks"]]
            got = wait_for(
                lambda: (
                    (x := c.get(f"/api/commands/{cmd['id']}").json())["status"] == "done"
                    and [ack["status"] for ack in x["acks"]] == expected
                    and x
                ),
                10,
                what="command done with every ack via replica B",
            )
            assert [ack["ts"] for ack in got["acks"]] == [ack["ts"] for ack in cmd["acks"]]
            listed = c.get(f"/api/robots/{ROBOTS[0]}/commands").json()
            assert [x["id"] for x in listed if x["id"] == cmd["id"]] == [cmd["id"]]

        # Let telemetry flow a little longer, then stop the robots and check the store.
        with a.client() as c:
            wait_for(
                lambda: all(
                    {s["stream"]: s for s in c.get(f"/api/robots/{r}/streams").json()}.get("position", {}).get(
                        "count", 0
                    )
                    > 300
                    for r in ROBOTS
                ),
                30,
                interval=0.3,
                what="telemetry stored",
            )
        for ag in agents:
            ag.stop()
        stored_by = {}
        for s in replicas:
            with s.client() as c:
                stored_by[s.port] = c.get("/api/stats").json()["writer"]["rows_submitted"]
        assert all(n > 0 for n in stored_by.values()), f"both replicas take a share of the ingest: {stored_by}"

        published = _published_max(probe)
        assert {r for r, _ in published} == set(ROBOTS)

        def _settled() -> tuple | None:
            dups, seqs = _duplicates_and_gaps(pg_url)
            complete = all(len(seqs.get(k, [])) >= top + 1 for k, top in published.items())
            return (dups, seqs) if complete else None

        dups, seqs = wait_for(_settled, 30, interval=0.5, what="every published seq stored")
        assert dups == [], "a telemetry message was stored more than once"
        for key, v in seqs.items():
            assert v == list(range(len(v))), f"{key}: gap in stored seqs"
        for robot in ROBOTS:
            assert len(seqs[(robot, "position")]) > 300
            assert seqs[(robot, "position")] == list(range(len(seqs[(robot, "position")])))
    finally:
        for s in replicas:
            s.stop()


def test_one_replica_runs_a_mission_and_another_takes_it_over_paused_when_it_dies(
    broker, pg_url, workdir, spawn_agent, mqtt_probe
):
    """A mission runs on the replica that started it (a row lease; its legs name that replica as their
    supervisor). The other mirrors it; a pause through it is applied by the owner. kill -9 of the owner: its
    robot stops within 1.5 s (its own motion reports) although the other replica still beats, and the other
    replica takes the mission over, paused with the reason; only the owner ever sent the mission's legs.
    Resume there carries on."""
    rid = "mrep-1"
    publish_site(mqtt_probe())
    probe = mqtt_probe(T.telemetry(rid, "motion"), T.ack(rid), T.heartbeat())
    a, b = replica_pair(broker, pg_url, workdir)
    a.start()
    b.start()
    try:
        spawn_agent(rid, "--disturbances", "--start-pose=-0.4,-0.4,1.57")
        area = [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]
        body = {"type": "coverage", "robots": [rid], "params": {"area": area, "sweep_width_m": 0.25}}
        with a.client() as ca, b.client() as cb:
            wait_ready(ca, [rid])
            wait_ready(cb, [rid])
            mid = cb.post("/api/missions", json=body).json()["id"]  # created through B, started through A
            wait_for(lambda: ca.get(f"/api/missions/{mid}").status_code == 200, 10, what="A mirrors the draft")
            r = ca.post(f"/api/missions/{mid}/start")
            assert r.status_code == 200 and r.json()["replica"] == "fleet-server-a", r.text
            wait_for(
                lambda: (
                    (m := cb.get(f"/api/missions/{mid}").json())["state"] == "running"
                    and m["replica"] == "fleet-server-a"
                ),
                10,
                what="B mirrors the running mission",
            )
            # a pause through B is asked of A, which applies it (B answers once it has, or 202 while pending)
            r = cb.post(f"/api/missions/{mid}/pause", json={"reason": "a look through B"})
            assert r.status_code in (200, 202), r.text
            if r.status_code == 202:
                assert r.json()["requested"] == "pause", r.text
            m = wait_state(cb, mid, ("paused", "completed", "failed", "aborted"), timeout=20)
            assert m["state"] == "paused" and m["replica"] == "fleet-server-a", m  # applied by its owner
            assert m["requested"] is None and m["reason"] == "a look through B", m
            # the operator who asked through B is the actor (as who started it through A), not the system
            assert m["transitions"][-1]["to_state"] == "paused"
            assert m["transitions"][-1]["actor"] == m["transitions"][1]["actor"] != "system"
            print(f"pause through B: {r.status_code}")
            assert all(p["status"] in ("paused", "done") for p in ca.get(f"/api/missions/{mid}").json()["progress"])
            r = ca.post(f"/api/missions/{mid}/resume")
            assert r.status_code == 200 and r.json()["replica"] == "fleet-server-a", r.text
            deadline = time.time() + 60
            while True:  # under way (a robot that dropped out ends the wait with the reason)
                m = ca.get(f"/api/missions/{mid}").json()
                p = m["progress"][0]
                if p["waypoint_index"] >= 1 and p["status"] == "moving":
                    break
                assert m["state"] == "running" and time.time() < deadline, (m["reason"], m["events"], p)
                time.sleep(0.3)
            killed = time.time()
            a.kill()  # kill -9 of the owner
            reports = wait_for(lambda: _stopped_since(probe, rid, killed), 10, what=f"{rid} stopped")
            assert moving_at(reports, killed), "the robot was not driving when its replica died: nothing proved"
            stop = first_stop_after(reports, killed)
            assert stop is not None
            print(f"owner killed: {rid} stopped {stop - killed:.3f} s later (its motion reports)")
            assert stop - killed <= 1.5, stop - killed
            beats = [orjson.loads(m.payload) for m in probe.matching(lambda m: m.topic == T.heartbeat())]
            assert any(h["server_id"] == "fleet-server-b" and killed < h["ts"] < stop for h in beats), (
                "B did not beat while the robot stopped: the test would not show that only its owner's beat counts"
            )

            def unsupervised() -> bool:  # the ack may come a moment after the wheels' stop report
                acks = [orjson.loads(m.payload) for m in probe.matching(lambda m: m.topic == T.ack(rid))]
                return any(
                    x["status"] == "failed"
                    and x["reason"].startswith("unsupervised: no heartbeat from server fleet-server-a")
                    for x in acks
                )

            wait_for(unsupervised, 10, what="the leg ended unsupervised: no heartbeat from server fleet-server-a")

            m = wait_state(cb, mid, ("paused", "completed", "failed", "aborted"), timeout=30)
            assert m["state"] == "paused" and m["replica"] == "fleet-server-b", m
            assert "fleet-server-a went silent" in m["reason"] and "taken over by fleet-server-b" in m["reason"]
            assert [t["to_state"] for t in m["transitions"]] == ["draft", "running", "paused", "running", "paused"]
            assert m["transitions"][-1]["actor"] == "system" != m["transitions"][1]["actor"]
            assert [e["detail"] for e in m["events"] if e["kind"] == "takeover"] == [
                {"from": "fleet-server-a", "to": "fleet-server-b"}
            ]
            legs = [x for x in cb.get(f"/api/robots/{rid}/commands").json() if x["source"] == f"mission:{mid}"]
            assert legs and {x["args"]["supervisor"] for x in legs} == {"fleet-server-a"}, legs

            r = cb.post(f"/api/missions/{mid}/resume")
            assert r.status_code == 200 and r.json()["replica"] == "fleet-server-b", r.text

            def resumed_leg() -> bool:
                cmds = cb.get(f"/api/robots/{rid}/commands").json()
                return any(
                    x["source"] == f"mission:{mid}"
                    and x["args"]["supervisor"] == "fleet-server-b"
                    and any(ack["status"] == "accepted" for ack in x["acks"])
                    for x in cmds
                )

            wait_for(resumed_leg, 20, interval=0.3, what="a leg from B accepted by the robot")
            assert cb.post(f"/api/missions/{mid}/abort").json()["state"] == "aborted"
    finally:
        a.stop()
        b.stop()


def _stopped_since(probe, rid: str, t: float) -> list[dict] | None:  # type: ignore[no-untyped-def]
    topic = T.telemetry(rid, "motion")
    reports = [orjson.loads(m.payload) for m in probe.matching(lambda m: m.topic == topic)]
    return reports if first_stop_after(reports, t) is not None else None
