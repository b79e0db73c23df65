"""The old-framework robots' shared broker account, ``legacy``, under the shipped ACL: it writes the old
framework's topics and nothing under fleet/ (the robot patterns would otherwise let it publish as a fleet
robot named "legacy"), and no robot can be given that account name."""

from __future__ import annotations

import subprocess
from pathlib import Path

from tests.deploy.test_acl_safety import _files
from tests.deploy.test_mosquitto import Client, shipped_broker
from tests.support.procs import VENV_BIN, base_env


def test_the_legacy_account_cannot_publish_as_a_fleet_robot() -> None:
    with shipped_broker("auth", _files()) as b:
        server = Client(
            b.port, username="fleet-server", password="pw-server", subscribe=("fleet/#", "robot/sensor_data/#")
        )
        legacy = Client(b.port, username="legacy", password="pw-legacy")
        try:
            server.wait_connected()
            legacy.wait_connected()
            for topic in (
                "fleet/legacy/status",
                "fleet/legacy/telemetry/position",
                "fleet/legacy/config",
                "fleet/legacy/ack",
                "fleet/legacy/time/req",
            ):
                legacy.publish(topic, b"{}")
            legacy.publish("robot/sensor_data/position", b"{}")  # allowed, and after the others on one link
            got = [t for t, _ in server.wait_for_topic("robot/sensor_data/position")]
            assert got == ["robot/sensor_data/position"], got
        finally:
            server.close()
            legacy.close()


def test_no_robot_can_get_the_legacy_account(tmp_path: Path) -> None:
    out = subprocess.run(
        [str(VENV_BIN / "fleet-server"), "robots", "add", "legacy", "--password-file", str(tmp_path / "passwd")],
        env=base_env(),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1 and "reserved" in out.stderr, out.stderr
    assert not (tmp_path / "passwd").exists()
