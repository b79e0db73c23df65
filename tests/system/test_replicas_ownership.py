"""With two server replicas, each lease, alarm and audit entry has one owner (issue 20): the replicas never
decide differently, and nothing is stored twice. Two replicas on one PostgreSQL database and one Mosquitto,
a robot played at the MQTT level (so that its battery reading is the test's)."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import create_engine, text

from tests.backend.helpers import ProbeRobot, audit_trail, operator_token, wait_robot
from tests.support.mqtt import MqttProbe
from tests.support.procs import Broker, replica_pair, wait_for

pytestmark = pytest.mark.postgres

ROBOT = "own-1"
DRIVE = {"command": "move_forward", "args": {"speed": 0.3, "duration_s": 0.3}}
ADMIN = "FLEET_ADMIN_TOKEN"


def _holder(c: httpx.Client) -> str | None:
    lease = c.get(f"/api/robots/{ROBOT}/lease").json()
    return lease["holder_name"] if lease else None


def _battery(c: httpx.Client) -> dict[str, Any] | None:
    return next((a for a in c.get("/api/alarms").json() if a["kind"] == "battery_critical"), None)


def _critical_active(c: httpx.Client) -> float:
    """This replica's own count (its memory, not the database): ``fleet_alarms_active`` in /metrics."""
    found = re.search(r'^fleet_alarms_active\{severity="critical"\} (\S+)$', c.get("/metrics").text, re.M)
    assert found is not None
    return float(found.group(1))


def _stored(url: str) -> tuple[list[tuple[Any, ...]], list[tuple[Any, ...]]]:
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            alarms = [
                tuple(r)
                for r in conn.execute(
                    text("SELECT id, state, acked_by FROM alarms WHERE robot_key = :r AND kind = 'battery_critical'"),
                    {"r": ROBOT},
                )
            ]
            transitions = [
                tuple(r)
                for r in conn.execute(
                    text(
                        "SELECT t.state, t.by FROM alarm_transitions t JOIN alarms a ON a.id = t.alarm_id "
                        "WHERE a.robot_key = :r AND a.kind = 'battery_critical' ORDER BY t.ts, t.id"
                    ),
                    {"r": ROBOT},
                )
            ]
    finally:
        engine.dispose()
    return alarms, transitions


def test_each_lease_alarm_and_audit_entry_has_one_owner(
    broker: Broker, pg_url: str, workdir: Path, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    replicas = replica_pair(broker, pg_url, workdir, ("1", "2"))
    for s in replicas:
        s.start()
    try:
        one, two = replicas
        robot = ProbeRobot(mqtt_probe, ROBOT, sensors=("position", "health"))
        robot.status()
        alice, _ = operator_token(one, "alice")  # tokens live in the shared database: valid on both
        bob, _ = operator_token(one, "bob")
        with (
            one.client(alice) as alice_1,
            two.client(bob) as bob_2,
            one.client() as admin_1,
            two.client() as admin_2,
        ):
            for c in (admin_1, admin_2):
                wait_robot(c, ROBOT, lambda r: r["online"])

            # -- the lease: taken through replica 1, refused through replica 2 naming its holder
            assert alice_1.post(f"/api/robots/{ROBOT}/commands", json=DRIVE).status_code == 202
            refused = bob_2.post(f"/api/robots/{ROBOT}/commands", json=DRIVE)
            assert refused.status_code == 409 and "driven by alice" in refused.json()["detail"], refused.text
            # an admin's takeover through replica 2 reaches replica 1 with nobody driving there ...
            taken = admin_2.post(f"/api/robots/{ROBOT}/lease?force=true")
            assert taken.status_code == 200 and taken.json()["holder_name"] == ADMIN, taken.text
            wait_for(lambda: _holder(admin_1) == ADMIN, 5, interval=0.1, what="replica 1 sees the takeover")
            # ... so that alice's next drive through replica 1 is refused
            refused = alice_1.post(f"/api/robots/{ROBOT}/commands", json=DRIVE)
            assert refused.status_code == 409 and f"driven by {ADMIN}" in refused.json()["detail"], refused.text
            assert admin_2.delete(f"/api/robots/{ROBOT}/lease").status_code == 204
            wait_for(lambda: _holder(admin_1) is None, 5, interval=0.1, what="replica 1 sees the release")

            # -- an alarm: both replicas watch the same health reading; one alarm row, each transition once
            robot.telemetry(0, {"battery_pct": 4.0, "cpu_temp_c": None}, stream="health")
            alarm = wait_for(lambda: _battery(admin_1), 5, interval=0.1, what="battery_critical raised")
            assert alarm["state"] == "active"
            wait_for(lambda: _critical_active(admin_1) == 1 and _critical_active(admin_2) == 1, 5, interval=0.1)
            # refused through both while the battery is critical; an admin's override through 2 holds on 1
            for c in (alice_1, bob_2):
                r = c.post(f"/api/robots/{ROBOT}/commands", json=DRIVE)
                assert r.status_code == 409 and r.json()["code"] == "battery_critical", r.text
            assert admin_2.post(f"/api/robots/{ROBOT}/battery-override").status_code == 200
            wait_for(
                lambda: alice_1.post(f"/api/robots/{ROBOT}/commands", json=DRIVE).status_code == 202,
                5,
                interval=0.2,
                what="replica 1 honours the override made through replica 2",
            )
            # acknowledged through replica 2: replica 1 shows it, from the database and in its own count
            acked = bob_2.post(f"/api/alarms/{alarm['id']}/ack")
            assert acked.status_code == 200 and acked.json()["acked_by"] == "bob", acked.text
            seen = _battery(admin_1)
            assert seen is not None and seen["state"] == "acknowledged" and seen["acked_by"] == "bob", seen
            wait_for(lambda: _critical_active(admin_1) == 0, 5, interval=0.1, what="replica 1's count drops")
            assert _critical_active(admin_2) == 0
            # the battery recovers: cleared once
            robot.telemetry(1, {"battery_pct": 80.0, "cpu_temp_c": None}, stream="health")
            for c in (admin_1, admin_2):
                wait_for(lambda c=c: (_battery(c) or {}).get("state") == "cleared", 5, interval=0.1, what="cleared")
            assert alice_1.post(f"/api/robots/{ROBOT}/commands", json=DRIVE).status_code == 202

        alarms, transitions = _stored(pg_url)
        assert [(state, by) for _, state, by in alarms] == [("cleared", "bob")], alarms
        assert transitions == [("active", "system"), ("acknowledged", "bob"), ("cleared", "system")], transitions

        # -- the audit trail: each action exactly once, whichever replica took it
        def trail() -> list[tuple[str, str]]:
            return [(e["actor_name"], e["action"]) for e in sorted(audit_trail(one), key=lambda e: (e["ts"], e["id"]))]

        expected = [
            (ADMIN, "token_create"),
            (ADMIN, "token_create"),
            ("alice", "lease_take"),
            ("alice", "command"),
            (ADMIN, "lease_take"),
            (ADMIN, "lease_takeover"),
            (ADMIN, "lease_release"),
            (ADMIN, "battery_override"),
            ("alice", "lease_take"),
            ("alice", "command"),
            ("bob", "alarm_ack"),
            ("alice", "command"),
        ]
        wait_for(lambda: len(trail()) >= len(expected), 5, interval=0.2, what="every audit entry stored")
        assert trail() == expected
        assert audit_trail(two) == audit_trail(one)
    finally:
        for s in replicas:
            s.stop()
