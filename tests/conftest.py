"""Fixtures build on each other: broker -> server -> robots. Every process is real and cleaned up."""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker, ServerProcess


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--database",
        default=os.environ.get("FLEET_TEST_DATABASE", "sqlite"),
        choices=["sqlite", "postgres"],
        help="database the server tests run against",
    )


@pytest.fixture
def workdir(tmp_path: Path) -> Path:
    return tmp_path


@pytest.fixture
def broker(workdir: Path) -> Iterator[Broker]:
    b = Broker(workdir)
    b.start()
    try:
        yield b
    finally:
        b.stop()


@pytest.fixture
def database_url(request: pytest.FixtureRequest, workdir: Path) -> Iterator[str]:
    """A fresh, empty database: a SQLite file, or a new schema-isolated PostgreSQL database."""
    kind = request.config.getoption("--database")
    if kind == "sqlite":
        yield f"sqlite:///{workdir / 'fleet.db'}"
        return
    import psycopg

    name = f"fleet_test_{uuid.uuid4().hex[:10]}"
    with psycopg.connect("postgresql://postgres@127.0.0.1:5432/test", autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"
    finally:
        with psycopg.connect("postgresql://postgres@127.0.0.1:5432/test", autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture
def server(broker: Broker, database_url: str, workdir: Path) -> Iterator[ServerProcess]:
    s = ServerProcess(broker, database_url, workdir)
    s.start()
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture
def spawn_agent(broker: Broker, workdir: Path) -> Iterator[Callable[..., AgentProcess]]:
    """Factory: ``spawn_agent("r1", "--rate", "50")`` starts a simulated robot agent."""
    agents: list[AgentProcess] = []

    def _spawn(robot_id: str, *extra_args: str, **env: str) -> AgentProcess:
        a = AgentProcess(robot_id, broker, workdir, list(extra_args), **env)
        a.start()
        agents.append(a)
        return a

    try:
        yield _spawn
    finally:
        for a in agents:
            a.stop()


@pytest.fixture
def mqtt_probe(broker: Broker) -> Iterator[Callable[..., MqttProbe]]:
    probes: list[MqttProbe] = []

    def _make(*subscriptions: str) -> MqttProbe:
        p = MqttProbe(broker.host, broker.port, list(subscriptions))
        probes.append(p)
        return p

    try:
        yield _make
    finally:
        for p in probes:
            p.close()
