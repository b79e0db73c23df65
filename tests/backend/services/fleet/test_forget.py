"""Forgetting a robot that is gone (``DELETE /api/robots/{id}``, ``fleet-server robots forget``), against a
real server, broker and simulated agent: the robot leaves the fleet list and the database, its retained
messages leave the broker (so it does not come back), its telemetry is kept or deleted as asked, and the
act is audited. An online robot, an unknown one and a caller who is not admin are refused."""

from __future__ import annotations

import sqlite3
import subprocess
import uuid
from pathlib import Path

import pytest

from tests.backend.helpers import wait_robot, writer_idle
from tests.support.mqtt import MqttProbe
from tests.support.procs import TEST_ADMIN_TOKEN, VENV_BIN, Broker, ServerProcess, base_env, wait_for


def _db_counts(server: ServerProcess, robot_id: str) -> dict[str, int]:
    path = server.database_url.removeprefix("sqlite:///")
    with sqlite3.connect(path) as conn:
        return {
            table: conn.execute(f"SELECT count(*) FROM {table} WHERE {col} = ?", (robot_id,)).fetchone()[0]
            for table, col in (
                ("robots", "id"),
                ("telemetry", "robot_id"),
                ("telemetry_1s", "robot_id"),
                ("telemetry_1m", "robot_id"),
                ("telemetry_dirty", "robot_id"),
                ("commands", "robot_id"),
            )
        }


def _retained(broker: Broker, robot_id: str) -> list[str]:
    """Topics under the robot that the broker holds retained (a marker round trip proves the retained
    messages, sent first on subscribe, have all arrived)."""
    marker = f"probe/sync/{uuid.uuid4().hex[:8]}"
    probe = MqttProbe(broker.host, broker.port, [f"fleet/{robot_id}/#", marker])
    try:
        probe.publish(marker, b"sync", qos=1)
        probe.wait(lambda m: m.topic == marker)
        return sorted({m.topic for m in probe.messages if m.retain and m.payload})
    finally:
        probe.client.disconnect()
        probe.client.loop_stop()


def _gone_offline(server: ServerProcess, spawn_agent, robot_id: str) -> None:
    agent = spawn_agent(robot_id, "--position-rate", "50")
    with server.client() as http:
        wait_robot(http, robot_id, lambda r: r["online"] and r["position"] is not None, timeout=30)
        r = http.post(f"/api/robots/{robot_id}/commands?wait=3", json={"command": "stop"})
        assert r.json()["status"] == "done", r.text
        wait_for(lambda: _db_counts(server, robot_id)["telemetry"] > 20, 15, what="stored telemetry")
        refused = http.delete(f"/api/robots/{robot_id}")
        assert refused.status_code == 409 and refused.json()["code"] == "robot_online", refused.text
        agent.stop()
        wait_robot(http, robot_id, lambda r: not r["online"], timeout=30)
        # its last telemetry may still wait in the writer's queue: counted before that is committed, the
        # rows kept would look like more than there were
        wait_for(lambda: writer_idle(http.get("/api/stats").json()["writer"]), 15, what="the writer to commit")


@pytest.mark.parametrize("telemetry", ["keep", "delete"])
def test_a_forgotten_robot_is_gone_from_the_server_and_the_broker(
    server: ServerProcess, broker: Broker, spawn_agent, telemetry: str
) -> None:
    _gone_offline(server, spawn_agent, "f1")
    before = _db_counts(server, "f1")
    assert before["robots"] == 1 and before["commands"] == 1
    retained = _retained(broker, "f1")
    assert "fleet/f1/status" in retained  # what would bring it back at the next subscribe
    with server.client() as http:
        operator = http.post("/api/tokens", json={"name": "op", "role": "operator"}).json()["token"]
        with server.client(token=operator) as op:
            r = op.delete("/api/robots/f1")
            assert r.status_code == 403 and r.json()["code"] == "forbidden"
        stats = http.get("/api/stats").json()
        received, rejects = stats["mqtt"]["received"], stats["rejects"]["total"]

        r = http.delete("/api/robots/f1", params={"telemetry": telemetry})
        assert r.status_code == 200, r.text
        assert r.json() == {
            "robot_id": "f1",
            "telemetry": telemetry,
            "rows_deleted": before["telemetry"] if telemetry == "delete" else 0,
        }

        assert "f1" not in [robot["id"] for robot in http.get("/api/robots").json()]
        gone = http.get("/api/robots/f1")
        assert gone.status_code == 404 and gone.json()["code"] == "unknown_robot"
        # the clears come back to the server too: applied as clears, not counted as malformed messages
        wait_for(
            lambda: http.get("/api/stats").json()["mqtt"]["received"] >= received + len(retained),
            10,
            what="the retained clears coming back",
        )
        assert http.get("/api/stats").json()["rejects"]["total"] == rejects
        assert http.get("/api/robots/f1").status_code == 404
        events = http.get("/api/events", params={"kind": "robot_forgotten"}).json()
        assert [(e["robot_id"], e["detail"]["by"], e["detail"]["telemetry"]) for e in events] == [
            ("f1", "env:admin", telemetry)
        ]
        again = http.delete("/api/robots/f1")
        assert again.status_code == 404 and again.json()["code"] == "unknown_robot"
        forgets = wait_for(
            lambda: http.get("/api/audit", params={"action": "robot_forget"}).json(), 5, what="the audit entry"
        )
        assert [(e["robot_id"], e["actor_name"], e["detail"]) for e in forgets] == [
            ("f1", "FLEET_ADMIN_TOKEN", {"telemetry": telemetry})
        ]

    assert _retained(broker, "f1") == []
    after = _db_counts(server, "f1")
    assert after["robots"] == 0 and after["commands"] == 1  # its commands stay: the history of what was done
    if telemetry == "keep":
        assert after["telemetry"] == before["telemetry"]
    else:
        assert after["telemetry"] == after["telemetry_1s"] == after["telemetry_1m"] == after["telemetry_dirty"] == 0


def test_fleet_server_robots_forget(server: ServerProcess, broker: Broker, spawn_agent) -> None:
    _gone_offline(server, spawn_agent, "f2")
    env = base_env(FLEET_ADMIN_TOKEN=TEST_ADMIN_TOKEN)
    cli = [str(VENV_BIN / "fleet-server"), "robots", "forget"]
    done = subprocess.run(
        [*cli, "f2", "--server", server.base_url, "--telemetry", "delete"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert "forgot robot f2" in done.stdout and "robots remove" in done.stdout
    assert _db_counts(server, "f2")["telemetry"] == 0 and _retained(broker, "f2") == []
    with server.client() as http:
        assert http.get("/api/robots/f2").status_code == 404
    again = subprocess.run(
        [*cli, "f2", "--server", server.base_url], env=env, capture_output=True, text=True, timeout=60
    )
    assert again.returncode == 1 and "unknown_robot" in again.stderr
    helptext = subprocess.run(
        [str(VENV_BIN / "fleet-server"), "robots", "--help"], env=env, capture_output=True, text=True, timeout=60
    ).stdout
    assert "forget" in helptext and "remove" in helptext and "credentials" in helptext


def test_forget_survives_a_server_restart(broker: Broker, database_url: str, workdir: Path, spawn_agent) -> None:
    """The retained status is what brought a forgotten robot back: after a restart (which subscribes again
    and gets every retained message) it stays gone; a robot not forgotten comes back the same way."""
    server = ServerProcess(broker, database_url, workdir)
    server.start()
    try:
        _gone_offline(server, spawn_agent, "f3")
        _gone_offline(server, spawn_agent, "kept")
        with server.client() as http:
            assert http.delete("/api/robots/f3").status_code == 200
    finally:
        server.stop()
    path = database_url.removeprefix("sqlite:///")
    with sqlite3.connect(path) as conn:  # the kept robot is known from its row; remove that to see it come back
        conn.execute("DELETE FROM robots WHERE id = 'kept'")
    server = ServerProcess(broker, database_url, workdir)
    server.start()
    try:
        with server.client() as http:
            wait_robot(http, "kept", lambda r: True, timeout=15)  # back from its retained status alone
            assert http.get("/api/robots/f3").status_code == 404
    finally:
        server.stop()
