"""More than one server: two replicas, one PostgreSQL database, one Mosquitto, three simulated robots.

Ingest goes through the MQTT v5 shared subscription ``$share/<group>/fleet/+/telemetry/#`` (each message
to one replica), so every telemetry message is stored exactly once; each replica also subscribes
non-shared to status, acks, e-stop and live telemetry for its own WebSocket clients. A command sent
through replica A is acked to a REST client and a WebSocket client of replica B.
"""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import Iterator

import orjson
import psycopg
import pytest
from sqlalchemy import create_engine, text

from tests.backend.helpers import ws_collect
from tests.support.procs import ServerProcess, wait_for

pytestmark = pytest.mark.postgres

ROBOTS = ("rep-1", "rep-2", "rep-3")
ADMIN_DSN = "postgresql://postgres@127.0.0.1:5432/test"


@pytest.fixture
def pg_url() -> Iterator[str]:
    """Replicas share a database, so this test always runs on PostgreSQL (whatever --database says)."""
    name = f"fleet_replicas_{uuid.uuid4().hex[:10]}"
    with psycopg.connect(ADMIN_DSN, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"
    finally:
        with psycopg.connect(ADMIN_DSN, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


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
    replicas = [
        ServerProcess(broker, pg_url, workdir, FLEET_INGEST_SHARED_GROUP="fleet-ingest",
                      FLEET_MQTT_CLIENT_ID=f"fleet-server-{name}")
        for name in ("a", "b")
    ]
    a, b = replicas
    a.start()  # the first replica migrates the schema; the second finds it at head
    b.start()
    try:
        agents = [spawn_agent(r, "--position-rate", "50") for r in ROBOTS]
        for s in replicas:
            with s.client() as c:
                wait_for(lambda c=c: all(c.get(f"/api/robots/{r}").status_code == 200
                                         and c.get(f"/api/robots/{r}").json()["online"] for r in ROBOTS),
                         20, interval=0.2, what="robots online on every replica")
                mqtt = c.get("/api/stats").json()["mqtt"]
                assert mqtt["protocol"] == "5"

        # Live telemetry of every robot reaches a WebSocket client of replica B (its own subscription).
        async def _live_on_b() -> list[dict]:
            msgs, _ = await ws_collect(
                b.ws_url, {"type": "subscribe", "robots": ["*"], "streams": ["position"]},
                lambda ms: {m["robot_id"] for m in ms if m["type"] == "telemetry"} >= set(ROBOTS), timeout=15,
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

        msgs, _ = asyncio.run(ws_collect(
            b.ws_url, {"type": "subscribe", "robots": [ROBOTS[0]], "streams": []}, _acked_on_b, timeout=15,
            on_open=_send_via_a,
        ))
        cmd = sent["cmd"]
        assert cmd["status"] == "done"
        on_b = [m["command"] for m in msgs if m["type"] == "command" and m["command"]["id"] == cmd["id"]]
        assert on_b[-1]["acks"][-1]["status"] == "done"
        with b.client() as c:
            # A publishes before its commit, so B may store an ack only on a retry, after A's own ack updates:
            # eventually both acks, each stored once (not once per replica), whatever the order of arrival
            expected = [ack["status"] for ack in cmd["acks"]]
            got = wait_for(lambda: (x := c.get(f"/api/commands/{cmd['id']}").json())["status"] == "done"
                           and [ack["status"] for ack in x["acks"]] == expected and x,
                           10, what="command done with every ack via replica B")
            assert [ack["ts"] for ack in got["acks"]] == [ack["ts"] for ack in cmd["acks"]]
            listed = c.get(f"/api/robots/{ROBOTS[0]}/commands").json()
            assert [x["id"] for x in listed if x["id"] == cmd["id"]] == [cmd["id"]]

        # Let telemetry flow a little longer, then stop the robots and check the store.
        with a.client() as c:
            wait_for(lambda: all(
                {s["stream"]: s for s in c.get(f"/api/robots/{r}/streams").json()}.get("position", {}).get(
                    "count", 0) > 300 for r in ROBOTS), 30, interval=0.3, what="telemetry stored")
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
