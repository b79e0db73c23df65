"""Fixtures for motion from the client (tests/fleet_client, tests/examples): a real server, broker and
simulated agents with the disturbances on. The test publishes the retained site itself (as the server
will), so that the agents accept goals."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from fleet_client import FleetClient
from fleet_protocol import QOS_SITE, Site, SiteMessage, Topics, default_pool_site, dumps, now
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker, ServerProcess


def publish_site(probe: MqttProbe, site: Site | None, version: int = 1) -> None:
    """The retained site message the server publishes (fleet_protocol Topics.site())."""
    msg = SiteMessage(version=version, site=site, ts=now())
    probe.publish(Topics().site(), dumps(msg), qos=QOS_SITE, retain=True)


@pytest.fixture
def server(broker: Broker, database_url: str, workdir: Path) -> Iterator[ServerProcess]:
    """The conftest's server, given up to 90 s to start: these tests run beside other helpers' test runs,
    and on two busy cores importing the server alone has taken over 30 s."""
    s = ServerProcess(broker, database_url, workdir)
    s.start(wait=False)
    try:
        s.wait_ready(90)
        yield s
    finally:
        s.stop()


@pytest.fixture
def pool_site(mqtt_probe: Callable[..., MqttProbe]) -> Site:
    site = default_pool_site()
    publish_site(mqtt_probe(), site)
    return site


@pytest.fixture
def fleet(server: ServerProcess) -> Iterator[FleetClient]:
    with FleetClient(server.base_url, token=server.token) as client:
        yield client


@pytest.fixture
def sim_robots(
    server: ServerProcess, spawn_agent: Callable[..., AgentProcess], fleet: FleetClient
) -> Callable[..., list[str]]:
    """Start simulated robots (disturbances on) at the given poses and wait until the server has them ready."""

    def _start(*poses: tuple[str, float, float, float], extra: tuple[str, ...] = ()) -> list[str]:
        agents = [spawn_agent(rid, "--disturbances", f"--start-pose={x},{y},{yaw}", *extra) for rid, x, y, yaw in poses]
        ids = [p[0] for p in poses]

        def ready() -> bool:
            for agent in agents:
                assert agent.alive(), f"agent {agent.robot_id} exited:\n{agent.output()[-2000:]}"
            robots = {r["id"]: r for r in fleet.robots()}
            # ready: online with a fix, its clock synchronised and the fleet's poses heard (a mission refuses a
            # robot whose clock is not known yet: 422, seen on a loaded machine)
            return all(rid in robots and robots[rid]["ready"] for rid in ids)

        deadline = time.monotonic() + 60
        while not ready():  # an agent that exits fails at once, with its output
            assert time.monotonic() < deadline, f"robots {ids} not ready within 60 s: {fleet.robots()}"
            time.sleep(0.1)
        time.sleep(1.0)  # the agents hear a few of the server's 5 Hz heartbeats (goals need supervision)
        return ids

    return _start
