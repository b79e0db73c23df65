"""Real processes for tests: a Mosquitto broker, the fleet server, simulated robot agents.

Every helper here starts a real OS process on free loopback ports and cleans it up; tests never mock
the broker, the server or the agent.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import shutil
import signal
import socket
import ssl
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx

REPO_ROOT = Path(__file__).resolve().parents[2]
VENV_BIN = Path(sys.executable).parent


#: Listening ports come from below the kernel's ephemeral range (32768-60999 here): a port the kernel
#: handed out with bind(0) can be taken by any outgoing connection before our server binds it ("address
#: already in use"); this range is only ever used by explicit binds. Each port is handed out once per run,
#: and each pytest process draws from its own slice of the range, so two never hand out the same port
#: between its check and its bind: an xdist worker takes slice ``FLEET_TEST_PORT_SLICE`` (set per lane by
#: scripts/test_lanes.py, since two lanes run side by side) plus its number; a run without workers the last.
_PORT_SPAN = (10000, 32000)
_PORT_SLICES = 12


def _worker_port_range() -> tuple[int, int]:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")  # "gw0", "gw1", ... under xdist; "" otherwise
    first = int(os.environ.get("FLEET_TEST_PORT_SLICE", "0"))
    index = (first + int(worker[2:])) % (_PORT_SLICES - 1) if worker[2:].isdigit() else _PORT_SLICES - 1
    width = (_PORT_SPAN[1] - _PORT_SPAN[0]) // _PORT_SLICES
    return _PORT_SPAN[0] + index * width, _PORT_SPAN[0] + (index + 1) * width


_PORT_RANGE = _worker_port_range()
_ports_given: set[int] = set()
#: ports in the span that browsers refuse to load (the one of Chromium's and Firefox's restricted ports above
#: 10000: net::ERR_UNSAFE_PORT, seen for a server on 10080 in a clean-clone run)
_BROWSER_UNSAFE_PORTS = frozenset({10080})


_ssl_context: ssl.SSLContext | None = None


def http_client(**options: Any) -> httpx.Client:
    """An ``httpx.Client`` sharing one TLS context per test process. httpx builds a new context for every
    client otherwise, loading the whole CA bundle each time (about 20 ms of CPU): polled once every 50 ms
    while a server starts, that alone kept a core busy. The servers here speak plain HTTP anyway."""
    global _ssl_context
    if _ssl_context is None:
        _ssl_context = httpx.create_ssl_context()
    return httpx.Client(verify=_ssl_context, **options)


def free_port() -> int:
    for _ in range(1000):
        port = random.randrange(*_PORT_RANGE)
        if port in _ports_given or port in _BROWSER_UNSAFE_PORTS:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        _ports_given.add(port)
        return port
    raise RuntimeError(f"no free port in {_PORT_RANGE}")


#: :func:`wait_for` polls at its ``interval`` for this long, then no faster than ``_SLOW_POLL_S``
_BRISK_S = 2.0
_SLOW_POLL_S = 0.2


def wait_for(predicate: Callable[[], Any], timeout: float = 10.0, interval: float = 0.05, what: str = "") -> Any:
    """Poll ``predicate`` until it returns a truthy value; raise AssertionError on timeout.

    Every ``interval`` for the first two seconds, then every 0.2 s: most predicates ask the server over
    HTTP, and a wait for a robot to cross the pool asked it 20 times a second for a minute, a tenth of a
    core per waiting test. Whatever happens within two seconds is still seen as soon as before."""
    start = time.monotonic()
    deadline = start + timeout
    last_exc: Exception | None = None
    while time.monotonic() < deadline:
        try:
            value = predicate()
            if value:
                return value
        except Exception as exc:
            last_exc = exc
        waited = time.monotonic() - start
        time.sleep(interval if waited < _BRISK_S else max(interval, _SLOW_POLL_S))
    raise AssertionError(f"timed out after {timeout}s waiting for {what or predicate}: last error {last_exc!r}")


async def wait_until(
    predicate: Callable[[], Any], timeout: float = 10.0, interval: float = 0.02, what: str = ""
) -> None:
    """:func:`wait_for` for code on an event loop: polls with ``asyncio.sleep``, so the loop under test
    keeps running; raise AssertionError on timeout."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout}s waiting for {what or predicate}")
        await asyncio.sleep(interval)


def wait_port(port: int, timeout: float = 10.0) -> None:
    def _open() -> bool:
        with socket.socket() as s:
            s.settimeout(0.2)
            return s.connect_ex(("127.0.0.1", port)) == 0

    wait_for(_open, timeout, what=f"port {port}")


def _stop_process(proc: subprocess.Popen[bytes], timeout: float = 5.0) -> None:
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


class Broker:
    """A real Mosquitto on a free loopback port, restartable on the same port."""

    def __init__(self, workdir: Path, extra_conf: str = "") -> None:
        exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
        if not Path(exe).exists():
            raise RuntimeError("mosquitto binary not found; install the Debian package 'mosquitto'")
        self.exe = exe
        self.port = free_port()
        self.host = "127.0.0.1"
        self.workdir = workdir
        self.conf = workdir / "mosquitto.conf"
        self.log = workdir / "mosquitto.log"
        self.conf.write_text(
            f"listener {self.port} 127.0.0.1\n"
            "allow_anonymous true\n"
            "persistence false\n"
            "set_tcp_nodelay true\n"
            "max_queued_messages 100000\n"
            "max_inflight_messages 1000\n"
            f"{extra_conf}\n"
        )
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"

    def start(self) -> None:
        self._logf = open(self.log, "ab")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen([self.exe, "-c", str(self.conf)], stdout=self._logf, stderr=subprocess.STDOUT)
        wait_port(self.port)

    def stop(self) -> None:
        if self.proc is not None:
            _stop_process(self.proc)
            self.proc = None
            self._logf.close()

    def kill(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait(5)
            self.proc = None
            self._logf.close()


#: FLEET_TEST_ZYGOTE=off starts every server and agent as a new executable (to compare, or to rule it out)
FORK_FROM_ZYGOTE = os.environ.get("FLEET_TEST_ZYGOTE", "on") != "off"


class ManagedProcess:
    """A Python console-script process with its output captured to a log file."""

    def __init__(self, name: str, argv: list[str], env: dict[str, str], logdir: Path) -> None:
        self.name = name
        self.argv = argv
        self.env = env
        self.log = logdir / f"{name}.log"
        self.proc: subprocess.Popen[bytes] | None = None

    #: "server" or "agent": started as a child forked from the test process's zygote of that kind
    #: (tests/support/zygote.py), the same code from the console script's ``main`` on without importing it
    #: again; None: a new process of the real executable (the tests of the command lines themselves).
    zygote: str | None = None

    def start(self) -> None:
        self._logf = open(self.log, "ab")  # noqa: SIM115 - closed in stop()
        if self.zygote is not None and FORK_FROM_ZYGOTE:
            from tests.support.zygote import Zygote

            self.proc = Zygote.get(self.zygote).spawn(self.argv, self.env, str(REPO_ROOT), self.log)  # type: ignore[assignment]
            return
        self.proc = subprocess.Popen(
            self.argv, env=self.env, stdout=self._logf, stderr=subprocess.STDOUT, cwd=str(REPO_ROOT)
        )

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self, timeout: float = 10.0) -> int | None:
        if self.proc is None:
            return None
        _stop_process(self.proc, timeout)
        rc = self.proc.returncode
        self.proc = None
        self._logf.close()
        return rc

    def kill(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait(5)
            self.proc = None
            self._logf.close()

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""


def base_env(**overrides: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("FLEET_", "DATABASE_URL"))}
    env["PYTHONUNBUFFERED"] = "1"
    env.update(overrides)
    return env


#: The FLEET_ADMIN_TOKEN every test server gets (authentication is on unless a test turns it off).
TEST_ADMIN_TOKEN = "test-admin-token-0123456789abcdefghijklmnop"
TEST_SECRET_KEY = "test-secret-key-0123456789abcdefghijklmnopq"


class ServerProcess(ManagedProcess):
    """``fleet-server`` on a free port against the given broker and database, with authentication on
    and ``TEST_ADMIN_TOKEN`` as FLEET_ADMIN_TOKEN (override with ``FLEET_AUTH="off"`` etc. in ``env``).
    ``client()``, ``ws_url`` and ``browser_auth()`` are authenticated as that admin."""

    zygote = "server"

    def __init__(self, broker: Broker, database_url: str, logdir: Path, **env: str) -> None:
        self.port = free_port()
        self.database_url = database_url
        self.broker = broker
        settings = {
            "FLEET_RUNS_DIR": str(logdir / "runs"),  # runs' camera frames stay in the test's own directory
            "FLEET_DATA_DIR": str(logdir / "server-data"),  # the client id's secret suffix, never the repo's ./data
            # a test machine runs several servers, agents and browsers on two cores: a loop late by 0.2 s is
            # common there, and its alarm banner would cover the controls the browser tests press
            # (tests/backend/core/test_loopwatch.py sets the real threshold)
            "FLEET_LOOP_STALL_ALARM_S": "5",
            "FLEET_AUTH": "on",
            "FLEET_ADMIN_TOKEN": TEST_ADMIN_TOKEN,
            "FLEET_SECRET_KEY": TEST_SECRET_KEY,
            **env,
        }
        auth_on = settings["FLEET_AUTH"].lower() not in ("off", "false", "0", "no")
        #: the admin bearer token (None when the server runs with FLEET_AUTH=off)
        self.token: str | None = settings["FLEET_ADMIN_TOKEN"] if auth_on else None
        self._browser_cookie: dict[str, Any] | None = None
        super().__init__(
            f"server-{self.port}",
            [str(VENV_BIN / "fleet-server"), "serve", "--host", "127.0.0.1", "--port", str(self.port)],
            base_env(
                FLEET_MQTT_URL=broker.url,
                FLEET_DATABASE_URL=database_url,
                FLEET_LOG_LEVEL="INFO",
                **settings,
            ),
            logdir,
        )

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def _ws(self, path: str, token: str | None) -> str:
        token = self.token if token is None else token
        return f"ws://127.0.0.1:{self.port}{path}" + (f"?token={token}" if token else "")

    @property
    def ws_url(self) -> str:
        """``/ws`` with the admin token as ``?token=`` (plain ``/ws`` when auth is off)."""
        return self._ws("/ws", None)

    def ws_camera_url(self, robot_id: str, token: str | None = None) -> str:
        return self._ws(f"/ws/camera/{robot_id}", token)

    def start(self, wait: bool = True) -> None:
        super().start()
        if wait:
            try:
                self.wait_ready()
            except BaseException:
                self.stop()  # a server that never got ready is stopped, not left running after the test
                raise

    def wait_ready(self, timeout: float = 30.0) -> None:
        with http_client(base_url=self.base_url, timeout=1.0) as http:

            def _ready() -> bool:
                if not self.alive():
                    raise RuntimeError(f"server exited:\n{self.output()[-3000:]}")
                r = http.get("/api/health")
                return r.status_code == 200 and r.json()["mqtt"]["connected"] is True

            wait_for(_ready, timeout, what="server health")

    def client(self, token: str | None = None, *, anonymous: bool = False) -> httpx.Client:
        """An HTTP client sending ``Authorization: Bearer`` (the admin token unless ``token`` is given);
        ``anonymous=True``: no credentials at all."""
        token = None if anonymous else (token or self.token)
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return http_client(base_url=self.base_url, timeout=15.0, headers=headers)

    def browser_auth(self) -> dict[str, Any]:
        """Playwright context options carrying a logged-in admin session cookie (created once per server)."""
        if self.token is None:
            return {}
        if self._browser_cookie is None:
            password = "browser-test-password"
            with self.client() as c:
                r = c.post("/api/users", json={"username": "browser-admin", "password": password, "role": "admin"})
                assert r.status_code in (201, 409), r.text
            with self.client(anonymous=True) as c:
                r = c.post("/api/auth/login", json={"username": "browser-admin", "password": password})
                assert r.status_code == 200, r.text
                value = r.cookies["fleet_session"]
            self._browser_cookie = {
                "name": "fleet_session",
                "value": value,
                "domain": "127.0.0.1",
                "path": "/",
                "expires": -1,
                "httpOnly": True,
                "secure": False,
                "sameSite": "Strict",
            }
        return {"storage_state": {"cookies": [self._browser_cookie], "origins": []}}


def replica_pair(
    broker: Broker, database_url: str, workdir: Path, names: tuple[str, str] = ("a", "b")
) -> list[ServerProcess]:
    """Two server replicas (not started) sharing one database and the ingest through one MQTT shared
    subscription, each with its own client id, as docs/scaling.md runs them."""
    return [
        ServerProcess(
            broker,
            database_url,
            workdir,
            FLEET_INGEST_SHARED_GROUP="fleet-ingest",
            FLEET_MQTT_CLIENT_ID=f"fleet-server-{name}",
        )
        for name in names
    ]


class AgentProcess(ManagedProcess):
    """``fleet-agent --simulate`` for one robot id."""

    zygote = "agent"

    def __init__(
        self, robot_id: str, broker: Broker, logdir: Path, extra_args: list[str] | None = None, **env: str
    ) -> None:
        self.robot_id = robot_id
        super().__init__(
            f"agent-{robot_id}",
            [
                str(VENV_BIN / "fleet-agent"),
                "--robot-id",
                robot_id,
                "--broker",
                broker.url,
                "--simulate",
                *(extra_args or []),
            ],
            base_env(**env),
            logdir,
        )


@contextlib.contextmanager
def temp_workdir(prefix: str = "fleet-test-") -> Iterator[Path]:
    path = Path(tempfile.mkdtemp(prefix=prefix))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


@contextlib.contextmanager
def agent_spawner(broker: Broker, workdir: Path) -> Iterator[Callable[..., AgentProcess]]:
    """``spawn("r1", "--rate", "50", **env)`` starts a simulated robot agent; every one is stopped on exit
    (the ``spawn_agent`` fixtures, per test and per module)."""
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
