"""The agent logs in to a broker with authentication on (the shipped Mosquitto config and ACL) with the
credentials `fleet-server robots add` makes: from the environment or flags it comes online, streams and
takes commands; with a wrong password the broker refuses it and it says so. With only a password the
username is the robot id. The password never appears in its log."""

from __future__ import annotations

from pathlib import Path

import orjson

from backend.core.broker_auth import set_broker_password
from fleet_protocol import Topics, dumps, new_command
from tests.deploy.test_mosquitto import DEPLOY, Client, shipped_broker
from tests.support.procs import AgentProcess, wait_for

T = Topics()
ROBOT_PASSWORD = "robot-one-password-0123456789"
SERVER_PASSWORD = "server-password-0123456789abcdef"


class _BrokerRef:
    """What AgentProcess needs of a broker."""

    def __init__(self, port: int) -> None:
        self.host, self.port, self.url = "127.0.0.1", port, f"mqtt://127.0.0.1:{port}"


def _auth_files(tmp_path: Path) -> dict[str, str]:
    passwd = tmp_path / "passwd"
    set_broker_password(passwd, "fleet-server", SERVER_PASSWORD)
    set_broker_password(passwd, "snail-1", ROBOT_PASSWORD)
    return {"passwd": passwd.read_text(), "acl": (DEPLOY / "mosquitto" / "acl.example").read_text()}


def test_agent_with_credentials_comes_online_and_a_wrong_password_is_refused(tmp_path: Path) -> None:
    with shipped_broker("auth", _auth_files(tmp_path)) as b:
        server = Client(b.port, username="fleet-server", password=SERVER_PASSWORD, subscribe=("fleet/#",))
        server.wait_connected()
        good = AgentProcess(
            "snail-1",
            _BrokerRef(b.port),
            tmp_path,  # type: ignore[arg-type]
            FLEET_AGENT_PASSWORD=ROBOT_PASSWORD,
        )  # username: the robot id
        bad = AgentProcess(
            "snail-1",
            _BrokerRef(b.port),
            tmp_path,  # type: ignore[arg-type]
            ["--username", "snail-1", "--password", "not-the-password"],
        )
        bad.name = "agent-snail-1-bad"
        try:
            good.start()
            got = server.wait_for_topic(T.telemetry("snail-1", "position"), count=5)
            statuses = [orjson.loads(p) for t, p in got if t == T.status("snail-1")]
            assert statuses and statuses[-1]["online"] is True
            cmd = new_command("stop", {})
            server.publish(T.cmd("snail-1"), dumps(cmd))
            acks = server.wait_for_topic(T.ack("snail-1"))
            assert any(orjson.loads(p)["id"] == cmd.id for t, p in acks if t == T.ack("snail-1"))

            bad.start()
            wait_for(lambda: "broker refused connection" in bad.output(), 15, what="the refusal in the log")
            assert bad.alive()  # it keeps retrying (a fixed password file brings it back)
            # the refused agent did not disturb the good one: it still answers a command
            cmd = new_command("stop", {})
            server.publish(T.cmd("snail-1"), dumps(cmd))
            wait_for(
                lambda: any(
                    orjson.loads(p)["id"] == cmd.id
                    for t, p in server.wait_for_topic(T.ack("snail-1"))
                    if t == T.ack("snail-1")
                ),
                10,
                what="the good agent's ack",
            )
            assert good.alive()
        finally:
            bad.stop()
            good.stop()
            server.close()
        for agent in (good, bad):
            assert ROBOT_PASSWORD not in agent.output() and "not-the-password" not in agent.output()
            assert "Traceback" not in agent.output()


def test_password_alone_logs_in_as_the_robot_id() -> None:
    from robot_agent.config import load_settings

    s = load_settings({"robot_id": "snail-7"}, environ={"FLEET_AGENT_PASSWORD": "secret-secret-secret"})
    assert s.username == "snail-7" and s.password is not None
    assert "secret-secret-secret" not in repr(s)
    empty = load_settings({"robot_id": "snail-7"}, environ={"FLEET_AGENT_PASSWORD": ""})
    assert empty.username is None and empty.password is None  # compose's unset variable: anonymous
