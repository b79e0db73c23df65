"""The fleet e-stop in the audit trail however it came (issue 29 #6): through the broker (``fleet-agent estop``
and the ``fleet-estop`` account, under the shipped ACL) as well as through the API; repeated engages coalesce
into the e-stop's one row; a copy of the server's own e-stop with another state is not passed off as audited."""

from __future__ import annotations

import subprocess
import time
import uuid
from pathlib import Path
from typing import Any

from fleet_protocol import EStop, Topics, dumps
from tests.backend.api.conftest import new_token
from tests.backend.helpers import audit_trail
from tests.support.acl_fleet import acl_fleet
from tests.support.mqtt import MqttProbe
from tests.support.procs import VENV_BIN, base_env, wait_for

ESTOP = Topics().estop()


def _estop_cli(port: int, password: str, *args: str) -> None:
    done = subprocess.run(
        [str(VENV_BIN / "fleet-agent"), "estop", "--broker", f"mqtt://127.0.0.1:{port}", *args],
        env=base_env(FLEET_ESTOP_PASSWORD=password),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr


def _estops(server: Any) -> list[dict[str, Any]]:
    return [e for e in audit_trail(server) if e["action"] in ("estop", "estop_release")]


def test_broker_estops_are_audited_once_and_repeats_coalesce(database_url: str, workdir: Path) -> None:
    with acl_fleet(workdir) as fleet:
        server = fleet.server(database_url)
        server.start()
        button = MqttProbe("127.0.0.1", fleet.port, username="fleet-estop", password=fleet.passwords["fleet-estop"])
        try:
            viewer = new_token(server, "viewer", "vic")
            with server.client() as admin, server.client(viewer) as vic:
                # engaged with the e-stop account, no server involved: audited with the source it gave
                _estop_cli(fleet.port, fleet.passwords["fleet-estop"], "--reason", "robot at the wall")
                wait_for(lambda: admin.get("/api/estop").json()["engaged"], 10, what="the broker's e-stop")
                # pressed again and again while engaged (a flood from the account, and a viewer): no row more
                for i in range(5):
                    msg = EStop(ts=time.time(), id=str(uuid.uuid4()), engaged=True, source=f"button-{i}")
                    button.publish(ESTOP, dumps(msg), retain=True)
                wait_for(lambda: admin.get("/api/estop").json()["source"] == "button-4", 10, what="the last press")
                assert vic.post("/api/estop", json={"reason": "me too"}).status_code == 202
                off = EStop(ts=time.time(), id=str(uuid.uuid4()), engaged=False, reason="clear", source="button-0")
                button.publish(ESTOP, dumps(off), retain=True)
                wait_for(lambda: not admin.get("/api/estop").json()["engaged"], 10, what="the broker's release")

                # a new latch through the API; then a copy of it that releases, with its signed id: not the server's
                pressed = vic.post("/api/estop", json={"reason": "again"}).json()
                forged = EStop(ts=time.time(), id=pressed["id"], engaged=False, source="forger")
                button.publish(ESTOP, dumps(forged), retain=True)
                wait_for(lambda: not admin.get("/api/estop").json()["engaged"], 10, what="the forged release")

            rows = wait_for(lambda: (r := _estops(server)) and len(r) >= 4 and r, 10, what="the e-stops' audit rows")
            engaged, released, again, copied = rows
            assert (engaged["action"], engaged["actor"], engaged["client"]) == ("estop", "broker", "mqtt")
            assert engaged["actor_name"].startswith("broker: fleet-agent estop@"), engaged
            detail = engaged["detail"]
            assert detail["reason"] == "robot at the wall" and detail["repeats"] == 6, detail
            assert detail["repeated_by"] == [*(f"broker: button-{i}" for i in range(5)), "vic"], detail
            assert (released["action"], released["actor_name"], released["detail"]["reason"]) == (
                "estop_release",
                "broker: button-0",
                "clear",
            )
            assert (again["action"], again["actor_name"], again["detail"]["id"]) == ("estop", "vic", pressed["id"])
            assert (copied["action"], copied["actor_name"]) == ("estop_release", "broker: forger")
            assert len(_estops(server)) == 4  # nothing else came later
        finally:
            button.close()
            server.stop()
