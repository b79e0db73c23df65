"""Fixtures build on each other: broker -> server -> robots. Every process is real and cleaned up."""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Callable, Generator, Iterator
from pathlib import Path

import pytest

from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker, ServerProcess, agent_spawner


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
    if request.config.getoption("--database") == "sqlite":
        yield f"sqlite:///{workdir / 'fleet.db'}"
        return
    with fresh_postgres("fleet_test") as url:
        yield url


@pytest.fixture
def pg_url() -> Iterator[str]:
    """A fresh PostgreSQL database whatever ``--database`` says: for replicas, which share one."""
    with fresh_postgres("fleet_replicas") as url:
        yield url


@contextlib.contextmanager
def fresh_postgres(prefix: str) -> Iterator[str]:
    """A new PostgreSQL database on 127.0.0.1:5432 for one test, dropped afterwards (connections and all)."""
    import psycopg

    admin = "postgresql://postgres@127.0.0.1:5432/test"
    name = f"{prefix}_{uuid.uuid4().hex[:10]}"
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"
    finally:
        with psycopg.connect(admin, autocommit=True) as conn:
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
    with agent_spawner(broker, workdir) as spawn:
        yield spawn


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


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None, None, None]:
    """Attach the server's log to the report of a failed test that ran one."""
    outcome = yield
    report = outcome.get_result()
    if report.failed:
        server = getattr(item, "funcargs", {}).get("server")
        if server is not None:
            report.sections.append(("server log (tail)", server.output()[-6000:]))
