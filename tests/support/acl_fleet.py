"""The shipped broker with authentication and the shipped ACL on (deploy/mosquitto/), and the fleet's real
processes logged in to it with their own accounts: the server as ``fleet-server``, each robot as its id,
``fleet-agent estop`` as ``fleet-estop``. For tests whose promise must hold under the production ACL."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from backend.core.broker_auth import mosquitto_hash
from tests.deploy.test_mosquitto import DEPLOY, ShippedBroker, shipped_broker
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, ServerProcess

#: robot accounts every AclFleet has (a robot's username is its id)
ROBOTS = ("robot-1", "robot-2", "robot-3")


class _BrokerRef:
    """What ServerProcess and AgentProcess read of a broker."""

    def __init__(self, port: int, url: str) -> None:
        self.host, self.port, self.url = "127.0.0.1", port, url


class AclFleet:
    def __init__(self, broker: ShippedBroker, workdir: Path, passwords: dict[str, str]) -> None:
        self.broker = broker
        self.workdir = workdir
        self.passwords = passwords

    @property
    def port(self) -> int:
        return self.broker.port

    @property
    def url(self) -> str:
        return f"mqtt://127.0.0.1:{self.port}"

    def server(self, database_url: str, **env: str) -> ServerProcess:
        """Not started; logs in as ``fleet-server``."""
        url = f"mqtt://fleet-server:{self.passwords['fleet-server']}@127.0.0.1:{self.port}"
        return ServerProcess(_BrokerRef(self.port, url), database_url, self.workdir, **env)  # type: ignore[arg-type]

    def agent(self, robot_id: str, *args: str, broker_url: str | None = None, **env: str) -> AgentProcess:
        """Not started; a simulated agent logged in with its own account (``broker_url``: e.g. a proxy)."""
        ref = _BrokerRef(self.port, broker_url or self.url)
        return AgentProcess(
            robot_id,
            ref,
            self.workdir,
            list(args),  # type: ignore[arg-type]
            FLEET_AGENT_PASSWORD=self.passwords[robot_id],
            **env,
        )

    def probe(self, *subscriptions: str) -> MqttProbe:
        """A client with the server's account (reads everything under the prefix, writes commands)."""
        return MqttProbe(
            "127.0.0.1",
            self.port,
            list(subscriptions),
            username="fleet-server",
            password=self.passwords["fleet-server"],
        )


@contextlib.contextmanager
def acl_fleet(workdir: Path) -> Iterator[AclFleet]:
    users = {user: f"pw-{user}-0123456789" for user in ("fleet-server", "fleet-estop", *ROBOTS)}
    passwd = "".join(f"{user}:{mosquitto_hash(pw)}\n" for user, pw in users.items())
    files = {"passwd": passwd, "acl": (DEPLOY / "mosquitto" / "acl.example").read_text()}
    with shipped_broker("auth", files) as b:
        yield AclFleet(b, workdir, users)
