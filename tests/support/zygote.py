"""A fork server for ``fleet-server`` and ``fleet-agent``: each program's code is imported once per test
process, and each test's server or simulated robot is a fresh child forked from it, with its own argv,
environment, working directory and log.

Importing the server (FastAPI, SQLAlchemy, Alembic, pydantic, uvicorn) costs about 1.6 s of CPU on the test
machine and the suite starts about 250 servers; the agent costs less, but the suite starts about 350. The
child runs exactly what the console script runs, ``backend.cli.main(argv)`` or ``robot_agent.cli.main(argv)``,
after the fork: nothing of the program is created before it (no settings, no event loop, no thread, no
socket), so a forked server or agent is the real one. The agent's zygote imports nothing of the server. Tests
of the command lines themselves, of the demo and of compose still start the real executables.

Protocol: the test process writes one JSON request a line on the zygote's stdin and reads one JSON answer a
line from its stdout: ``{"spawn": {"argv", "env", "cwd", "log"}}`` -> ``{"pid"}``; ``{"poll": pid}`` ->
``{"returncode": int | null}``.
"""

from __future__ import annotations

import atexit
import importlib
import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any, ClassVar

#: each kind: the module whose ``main(argv)`` the console script calls, and what the zygote imports up front
KINDS: dict[str, tuple[str, tuple[str, ...]]] = {
    "server": (
        "backend.cli",
        (
            "backend.main",
            "backend.store.db",
            "uvicorn.config",
            "uvicorn.server",
            "uvicorn.lifespan.on",
            "uvicorn.loops.auto",
            "uvicorn.protocols.http.h11_impl",
            "uvicorn.protocols.websockets.websockets_sansio_impl",
            "sqlalchemy.dialects.sqlite",
            "sqlalchemy.dialects.postgresql.psycopg",
            "alembic.command",
            "paho.mqtt.client",
        ),
    ),
    "agent": ("robot_agent.cli", ("robot_agent.agent", "robot_agent.config", "robot_agent.sim", "paho.mqtt.client")),
}


def _child(entry: str, request: dict[str, Any], control: tuple[int, int]) -> None:  # pragma: no cover - a fork
    """In the forked child: become the program with the request's argv and environment; never return."""
    code: int = 1
    try:
        os.close(control[1])  # the answers pipe; stdin (the requests) is replaced just below
        devnull = os.open(os.devnull, os.O_RDONLY)
        os.dup2(devnull, 0)
        if devnull != 0:
            os.close(devnull)
        log = os.open(request["log"], os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        os.dup2(log, 1)
        os.dup2(log, 2)
        os.close(log)
        os.environ.clear()
        os.environ.update(request["env"])
        os.chdir(request["cwd"])
        random.seed()  # the zygote's random state would otherwise be every child's
        sys.argv = [request["prog"], *request["argv"]]
        result = importlib.import_module(entry).main(request["argv"])
        code = int(result or 0)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:
        traceback.print_exc()
        code = 1
    finally:
        try:
            atexit._run_exitfuncs()  # what an interpreter's normal exit runs (log handlers, queue listeners)
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def serve(kind: str) -> None:
    """The zygote's loop: preload, then answer requests until stdin closes."""
    entry, preload = KINDS[kind]
    for name in (entry, *preload):
        importlib.import_module(name)
    requests = sys.stdin.buffer
    answers = os.fdopen(os.dup(1), "wb")  # the answers get a pipe of their own ...
    os.dup2(2, 1)  # ... and anything printed goes to stderr, never into the protocol
    control = (requests.fileno(), answers.fileno())
    codes: dict[int, int] = {}
    for line in requests:
        request = json.loads(line)
        if "spawn" in request:
            pid = os.fork()
            if pid == 0:
                _child(entry, request["spawn"], control)
            answer: dict[str, Any] = {"pid": pid}
        else:
            pid = int(request["poll"])
            if pid not in codes:
                done, status = os.waitpid(pid, os.WNOHANG)
                if done:
                    codes[pid] = os.waitstatus_to_exitcode(status)
            answer = {"returncode": codes.get(pid)}
        answers.write(json.dumps(answer).encode() + b"\n")
        answers.flush()


class Zygote:
    """The test process's handle on its fork server (one per process, started on first use)."""

    _instances: ClassVar[dict[str, Zygote]] = {}
    _lock = threading.Lock()

    def __init__(self, kind: str) -> None:
        self.kind = kind
        env = {k: v for k, v in os.environ.items() if not k.startswith(("FLEET_", "DATABASE_URL"))}
        env["PYTHONUNBUFFERED"] = "1"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.support.zygote", kind],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            cwd=str(Path(__file__).resolve().parents[2]),
            env=env,
        )
        self._io = threading.Lock()

    @classmethod
    def get(cls, kind: str) -> Zygote:
        """This process's zygote of ``kind`` ("server" or "agent"), started on first use."""
        with cls._lock:
            zygote = cls._instances.get(kind)
            if zygote is None or zygote.proc.poll() is not None:
                zygote = cls._instances[kind] = Zygote(kind)
                atexit.register(zygote.close)
            return zygote

    def ask(self, request: dict[str, Any]) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        with self._io:
            self.proc.stdin.write(json.dumps(request).encode() + b"\n")
            self.proc.stdin.flush()
            line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the server zygote exited (status {self.proc.poll()})")
        answer: dict[str, Any] = json.loads(line)
        return answer

    def spawn(self, argv: list[str], env: dict[str, str], cwd: str, log: Path) -> ForkedProcess:
        """Fork ``argv`` (the console script's path, then its arguments) as a child of the zygote."""
        request = {"prog": Path(argv[0]).name, "argv": argv[1:], "env": env, "cwd": cwd, "log": str(log)}
        pid = int(self.ask({"spawn": request})["pid"])
        return ForkedProcess(self, pid)

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


class ForkedProcess:
    """What tests use of :class:`subprocess.Popen` (pid, poll, wait, send_signal, terminate, kill,
    returncode) for a server forked by the zygote, whose parent is the zygote, not the test."""

    def __init__(self, zygote: Zygote, pid: int) -> None:
        self.zygote = zygote
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            self.returncode = self.zygote.ask({"poll": self.pid})["returncode"]
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while (code := self.poll()) is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired([f"forked {self.zygote.kind}", str(self.pid)], timeout or 0)
            time.sleep(0.01)
        return code

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


if __name__ == "__main__":
    serve(sys.argv[1])
