"""`fleet-server robots add ID` prints a one-line enrolment for the Pi, and no password (issue 29 #3): the
broker account goes into the password file, a single-use token into the server's database; `fleet-agent
enrol` (what `install-pi.sh --enrol` runs) exchanges the token once at the running server for the robot's
password and the fleet key, writes them into the agent's config (0600), and the robot comes online on the
shipped broker (authentication on, acl.example) with nothing typed. Real CLI, server, broker and agent."""

from __future__ import annotations

import os
import re
import subprocess
import tomllib
from pathlib import Path

from backend.core.broker_auth import read_password_file, set_broker_password, verify_mosquitto_hash
from fleet_protocol import Topics
from tests.deploy.test_mosquitto import DEPLOY, Client, ShippedBroker
from tests.support.procs import VENV_BIN, ManagedProcess, ServerProcess, base_env, wait_for

T = Topics()
SERVER_PASSWORD = "server-password-0123456789abcdef"
ROBOT = "snail-e1"
LINE = re.compile(r"^sudo \./robot_agent/deploy/install-pi\.sh --enrol (\S+) (fle_[A-Za-z0-9_-]{43})$")
MOSQUITTO_UID = 1883


def _run(exe: str, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(VENV_BIN / exe), *args], env=base_env(**env), capture_output=True, text=True, timeout=60)


def test_robots_add_prints_an_enrolment_that_works_once_and_brings_the_robot_online(
    broker, database_url: str, workdir: Path
) -> None:
    b = ShippedBroker("auth", {"acl": (DEPLOY / "mosquitto" / "acl.example").read_text()})
    passwd = b.dir / "auth" / "passwd"
    set_broker_password(passwd, "fleet-server", SERVER_PASSWORD)
    passwd.chmod(0o644)  # the test's broker drops root to the mosquitto user (ShippedBroker's files are 0644)
    if os.geteuid() == 0:  # compose runs this as root in the server container: the broker keeps its file
        os.chown(passwd, MOSQUITTO_UID, MOSQUITTO_UID)
    server = ServerProcess(broker, database_url, workdir)
    server.start()
    try:
        added = _run(
            "fleet-server",
            *("robots", "add", ROBOT, "--password-file", str(passwd), "--enrol-url", server.base_url),
            *("--broker", f"mqtt://127.0.0.1:{b.port}"),
            FLEET_DATABASE_URL=database_url,
        )
        assert added.returncode == 0, added.stderr
        (line,) = added.stdout.splitlines()  # one line for the Pi, the rest on stderr
        m = LINE.match(line)
        assert m is not None, line
        assert m.group(1) == server.base_url
        token = m.group(2)
        assert ROBOT in read_password_file(passwd) and "before" in added.stderr
        if os.geteuid() == 0:
            assert passwd.stat().st_uid == MOSQUITTO_UID
        with server.client(anonymous=True) as c:  # a made-up token: 404, and nothing handed out
            r = c.post("/api/enrol", json={"token": "fle_" + "A" * 43})
            assert r.status_code == 404 and r.json()["code"] == "enrolment_unknown", r.text

        config = workdir / "agent.toml"
        config.write_text('robot_id = "placeholder"\nsimulate = true\n\n[discovery]\nmdns = false\n')
        enrolled = _run("fleet-agent", "enrol", server.base_url, token, "--config", str(config))
        assert enrolled.returncode == 0, enrolled.stderr
        assert f"enrolled as robot {ROBOT}" in enrolled.stdout
        assert oct(config.stat().st_mode & 0o777) == "0o600"
        settings = tomllib.loads(config.read_text())
        assert settings["robot_id"] == ROBOT and settings["username"] == ROBOT and settings["simulate"] is True
        assert settings["broker"] == f"mqtt://127.0.0.1:{b.port}"
        assert verify_mosquitto_hash(settings["password"], read_password_file(passwd)[ROBOT])
        assert settings["fleet_key"] == (workdir / "server-data" / "fleet-key.secret").read_text().strip()
        for shown in (added.stdout, added.stderr, enrolled.stdout, enrolled.stderr):
            assert settings["password"] not in shown and settings["fleet_key"] not in shown

        again = _run("fleet-agent", "enrol", server.base_url, token, "--config", str(workdir / "second.toml"))
        assert again.returncode == 1 and "410" in again.stderr and "enrolment_used" in again.stderr
        assert not (workdir / "second.toml").exists()

        b.start()
        probe = Client(b.port, username="fleet-server", password=SERVER_PASSWORD, subscribe=(T.status(ROBOT),))
        probe.wait_connected()
        agent = ManagedProcess(
            f"agent-{ROBOT}", [str(VENV_BIN / "fleet-agent"), "--config", str(config)], base_env(), workdir
        )
        agent.zygote = "agent"
        agent.start()
        try:
            probe.wait_for_topic(T.status(ROBOT))
            wait_for(lambda: b'"online":true' in probe.got[-1][1], 20, what="the enrolled robot online")
        finally:
            agent.stop()
            probe.close()
        assert settings["password"] not in agent.output()
    finally:
        server.stop()
        b.stop()
        b.close()
    assert f"robot {ROBOT} enrolled from 127.0.0.1" in server.output()
