"""The shipped broker config with authentication on (deploy/mosquitto/: password file + acl.example) and
credentials made by ``fleet-server broker-user`` / ``fleet-server robots add``, with a real fleet server
logged in to the broker: anonymous and wrong passwords are refused; robot A's credentials can neither
publish into robot B's namespace (the broker acks, nobody receives it) nor read B's commands."""

from __future__ import annotations

import re
import subprocess
import time
from pathlib import Path

import orjson

from backend.core.broker_auth import read_password_file, verify_mosquitto_hash
from tests.deploy.test_mosquitto import DEPLOY, Client, shipped_broker
from tests.support.procs import VENV_BIN, ServerProcess, base_env, wait_for


def _cli(*args: str) -> str:
    out = subprocess.run(
        [str(VENV_BIN / "fleet-server"), *args], env=base_env(), capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    return out.stdout


def _credentials(passwd: Path) -> tuple[str, dict[str, str]]:
    """The server's broker URL (with its password) and each robot's password, as the CLI printed them."""
    url = re.search(
        r"^FLEET_MQTT_URL=(\S+)$", _cli("broker-user", "--password-file", str(passwd), "--broker-host", "HOST"), re.M
    )
    assert url is not None
    robots = {}
    for rid in ("snail-1", "snail-2"):
        # --print-password: the hand-made agent config (the default prints an enrolment: tests/backend/cli/)
        out = _cli(
            "robots", "add", rid, "--password-file", str(passwd), "--broker", "mqtt://base.lab:1883", "--print-password"
        )
        assert f'robot_id = "{rid}"' in out and f'username = "{rid}"' in out
        assert 'broker = "mqtt://base.lab:1883"' in out
        m = re.search(r'^password = "(\S+)"$', out, re.M)
        assert m is not None
        robots[rid] = m.group(1)
        assert f"FLEET_AGENT_PASSWORD={m.group(1)}" in out
    return url.group(1), robots


def test_robots_add_writes_mosquitto_compatible_entries(tmp_path: Path) -> None:
    passwd = tmp_path / "passwd"
    _, robots = _credentials(passwd)
    entries = read_password_file(passwd)
    assert set(entries) == {"fleet-server", "snail-1", "snail-2"}
    assert all(e.startswith("$7$") for e in entries.values())
    assert verify_mosquitto_hash(robots["snail-1"], entries["snail-1"])
    assert oct(passwd.stat().st_mode & 0o777) == "0o600"
    # again: the robot's entry is replaced (new password), nobody else's
    before = dict(entries)
    _cli("robots", "add", "snail-1", "--password-file", str(passwd), "--print-password")
    after = read_password_file(passwd)
    assert after["snail-1"] != before["snail-1"] and after["snail-2"] == before["snail-2"]
    _cli("robots", "remove", "snail-2", "--password-file", str(passwd))
    assert set(read_password_file(passwd)) == {"fleet-server", "snail-1"}
    bad = subprocess.run(
        [str(VENV_BIN / "fleet-server"), "robots", "add", "fleet-server", "--password-file", str(passwd)],
        env=base_env(),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 1 and "reserved" in bad.stderr  # a robot can never get the server's account


def test_acl_with_a_real_server(tmp_path: Path) -> None:
    passwd = tmp_path / "passwd"
    server_url, pw = _credentials(passwd)
    files = {"passwd": passwd.read_text(), "acl": (DEPLOY / "mosquitto" / "acl.example").read_text()}
    with shipped_broker("auth", files) as b:
        anonymous = Client(b.port)
        assert anonymous.dropped.wait(10) and not anonymous.connected.is_set()
        anonymous.c.loop_stop()
        wrong = Client(b.port, username="snail-1", password=pw["snail-2"])  # B's password is not A's
        assert wrong.dropped.wait(10) and not wrong.connected.is_set()
        wrong.c.loop_stop()

        broker = _BrokerRef(b.port, server_url.replace("HOST", f"127.0.0.1:{b.port}"))
        server = ServerProcess(broker, f"sqlite:///{tmp_path / 'fleet.db'}", tmp_path)  # type: ignore[arg-type]
        a = Client(b.port, username="snail-1", password=pw["snail-1"], subscribe=("fleet/#",))
        bee = Client(b.port, username="snail-2", password=pw["snail-2"], subscribe=("fleet/snail-2/cmd",))
        spy = Client(b.port, username="fleet-server", password=_server_password(server_url), subscribe=("fleet/#",))
        try:
            server.start()  # logs in to the broker with its own credentials, or never gets healthy
            for c in (a, bee, spy):
                c.wait_connected()
            status = {"online": True, "ts": time.time(), "capabilities": {"sensors": [], "commands": ["stop"]}}

            # A impersonates B: the broker acks the publish (MQTT 3.1.1 cannot refuse it) but drops it
            a.publish("fleet/snail-2/status", orjson.dumps(status), retain=True)
            a.publish("fleet/snail-2/telemetry/position", b'{"ts": 1, "seq": 1, "data": {"x": 9, "y": 9}}')
            a.publish("fleet/snail-1/status", orjson.dumps(status), retain=True)  # then its own: delivered
            spy.wait_for_topic("fleet/snail-1/status")
            # what the robots published (the server's own site and heartbeat are on fleet/# too)
            assert [t for t, _ in spy.got if t.startswith("fleet/snail")] == ["fleet/snail-1/status"]
            a.wait_for_topic("fleet/site")  # a robot's account reads the site the server publishes
            with server.client() as c:
                wait_for(lambda: any(r["id"] == "snail-1" for r in c.get("/api/robots").json()), 10)
                assert [r["id"] for r in c.get("/api/robots").json()] == ["snail-1"]

                # B is real; the server commands B: B gets it, A (subscribed to fleet/#) never does
                bee.publish("fleet/snail-2/status", orjson.dumps(status), retain=True)
                wait_for(lambda: c.get("/api/robots/snail-2").status_code == 200, 10)
                r = c.post("/api/robots/snail-2/commands", json={"command": "stop"})
                assert r.status_code == 202, r.text
                bee.wait_for_topic("fleet/snail-2/cmd")
                r = c.post("/api/robots/snail-1/commands", json={"command": "stop"})
                assert r.status_code == 202
                got = [t for t, _ in a.wait_for_topic("fleet/snail-1/cmd")]  # A's own arrives, after B's
                assert "fleet/snail-2/cmd" not in got and "fleet/snail-2/status" not in got
                # and a robot cannot engage or release the fleet e-stop for everyone
                a.publish("fleet/estop", b'{"ts": 1, "engaged": false}', retain=True)
                assert c.get("/api/estop").json()["engaged"] is False
        finally:
            server.stop()
            for c in (a, bee, spy):
                c.close()
        assert _server_password(server_url) not in server.output()  # the broker password never in logs


class _BrokerRef:
    """What ServerProcess needs of a broker (its URL comes from FLEET_MQTT_URL here)."""

    def __init__(self, port: int, url: str) -> None:
        self.host, self.port, self.url = "127.0.0.1", port, url


def _server_password(url: str) -> str:
    m = re.match(r"mqtt://fleet-server:([^@]+)@", url)
    assert m is not None
    return m.group(1)
