"""Fixtures build on each other: broker -> server -> robots. Every process is real and cleaned up."""

from __future__ import annotations

import contextlib
import os
import shutil
import uuid
from collections.abc import Callable, Generator, Iterator
from pathlib import Path

import pytest

from tests.support.cputime import tree_cpu_seconds
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


@pytest.fixture(scope="session")
def migrated_template(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A database migrated to head once per test process (each xdist worker has its own): a SQLite file, or
    a PostgreSQL database used as ``TEMPLATE``. :func:`database_url` copies it for every test, so a server
    starts on a schema already at head instead of running every migration again."""
    from backend.core.config import Settings
    from backend.store.db import create_db_engine, upgrade_to_head

    if request.config.getoption("--database") == "sqlite":
        path = tmp_path_factory.mktemp("template") / "fleet.db"
        engine = create_db_engine(Settings(database_url=f"sqlite:///{path}"))
        try:
            upgrade_to_head(engine)
            with engine.connect() as conn:  # everything into the main file: the copy takes that file alone
                conn.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)")
        finally:
            engine.dispose()
        yield str(path)
        return
    import psycopg

    name = f"fleet_template_{uuid.uuid4().hex[:10]}"
    with psycopg.connect(POSTGRES_ADMIN, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        engine = create_db_engine(Settings(database_url=f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"))
        try:
            upgrade_to_head(engine)
        finally:
            engine.dispose()  # a template may have no open connection when it is copied
        yield name
    finally:
        with psycopg.connect(POSTGRES_ADMIN, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture
def database_url(request: pytest.FixtureRequest, workdir: Path, migrated_template: str) -> Iterator[str]:
    """A fresh database of this test's own, its schema at head: a copy of the run's migrated SQLite file, or a
    new PostgreSQL database made from the migrated template. Tests of the migrations take
    :func:`empty_database_url`."""
    if request.config.getoption("--database") == "sqlite":
        target = workdir / "fleet.db"
        shutil.copyfile(migrated_template, target)
        yield f"sqlite:///{target}"
        return
    with fresh_postgres("fleet_test", template=migrated_template) as url:
        yield url


@pytest.fixture
def empty_database_url(request: pytest.FixtureRequest, workdir: Path) -> Iterator[str]:
    """A fresh, empty database (no schema at all): a SQLite file, or a new PostgreSQL database."""
    if request.config.getoption("--database") == "sqlite":
        yield f"sqlite:///{workdir / 'empty.db'}"
        return
    with fresh_postgres("fleet_empty") as url:
        yield url


@pytest.fixture
def pg_url() -> Iterator[str]:
    """A fresh PostgreSQL database whatever ``--database`` says: for replicas, which share one."""
    with fresh_postgres("fleet_replicas") as url:
        yield url


POSTGRES_ADMIN = "postgresql://postgres@127.0.0.1:5432/test"


@contextlib.contextmanager
def fresh_postgres(prefix: str, template: str | None = None) -> Iterator[str]:
    """A new PostgreSQL database on 127.0.0.1:5432 for one test (empty, or a copy of ``template``), dropped
    afterwards (connections and all)."""
    import psycopg

    name = f"{prefix}_{uuid.uuid4().hex[:10]}"
    copy = f' TEMPLATE "{template}"' if template else ""
    with psycopg.connect(POSTGRES_ADMIN, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"{copy}')
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"
    finally:
        with psycopg.connect(POSTGRES_ADMIN, autocommit=True) as conn:
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


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Keep a module's tests on one pytest-xdist worker when they share a module-scoped fixture (a browser, a
    fleet, a schema): the fixture then starts once, not once per worker that happens to get one of its tests.
    ``--dist loadgroup`` sends each group whole to one worker and spreads every other test one by one."""
    for item in items:
        if item.get_closest_marker("xdist_group") is not None:
            continue
        info = getattr(item, "_fixtureinfo", None)
        defs = info.name2fixturedefs.values() if info is not None else ()
        if any(d.scope in ("module", "package", "session") and d.baseid for fds in defs for d in fds):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::", 1)[0]))
    # the largest groups first (longest job first): a group goes whole to one worker, so one that started
    # last would run on alone while the other workers sit idle; every worker collects the same order
    groups = [_group(item) for item in items]
    sizes = {g: groups.count(g) for g in set(groups) if g is not None}
    order = {
        id(item): (0, -sizes[g], g) if g is not None else (1, 0, "") for item, g in zip(items, groups, strict=True)
    }
    items.sort(key=lambda item: order[id(item)])


def _group(item: pytest.Item) -> str | None:
    marker = item.get_closest_marker("xdist_group")
    if marker is None:
        return None
    return str(marker.args[0] if marker.args else marker.kwargs.get("name", ""))


_CPU_BEFORE = pytest.StashKey[float]()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Generator[None, None, None]:
    """Record the CPU seconds the test's process tree used, setup to teardown (``cpu_s``: make test-report
    lists the heaviest), to tell the tests that load the machine from those that wait for robots."""
    item.stash[_CPU_BEFORE] = tree_cpu_seconds()
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None, None, None]:
    """Record each phase's duration; attach the server's log to the report of a failed test that ran one."""
    outcome = yield
    report = outcome.get_result()
    # each phase's time goes into the JUnit report as a property of its test (make test-report reads them):
    # a report copies the item's properties when it is made, and the teardown report's are the ones written
    phase = (f"{report.when}_s", f"{report.duration:.3f}")
    (report if report.when == "teardown" else item).user_properties.append(phase)
    if report.when == "teardown" and _CPU_BEFORE in item.stash:
        report.user_properties.append(("cpu_s", f"{tree_cpu_seconds() - item.stash[_CPU_BEFORE]:.2f}"))
    if report.failed:
        server = getattr(item, "funcargs", {}).get("server")
        if server is not None:
            report.sections.append(("server log (tail)", server.output()[-6000:]))
