"""`make demo`'s script as a user runs it: real broker, server and agents; Ctrl-C stops all of it."""

from __future__ import annotations

import contextlib
import math
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest

from tests.support.procs import wait_for

ROOT = Path(__file__).resolve().parents[2]


def _processes() -> dict[int, tuple[int, int, str]]:
    """pid -> (ppid, pgid, start time) of every process on the machine."""
    out: dict[int, tuple[int, int, str]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] == "Z":
            continue
        out[int(entry.name)] = (int(fields[1]), int(fields[2]), fields[19])
    return out


def _descendants(pid: int) -> dict[int, tuple[int, str]]:
    """Every live descendant of ``pid``: pid -> (pgid, start time)."""
    procs = _processes()
    found: dict[int, tuple[int, str]] = {}
    frontier = [pid]
    while frontier:
        parent = frontier.pop()
        for child, (ppid, pgid, start) in procs.items():
            if ppid == parent and child not in found:
                found[child] = (pgid, start)
                frontier.append(child)
    return found


class Demo:
    """scripts/demo.py as a subprocess; its stdout is read by a thread so no read ever blocks the test."""

    def __init__(self, tmp: Path, *args: str, **fleet_env: str) -> None:
        env = {k: v for k, v in os.environ.items() if not k.startswith("FLEET_")}
        env.update(fleet_env)
        env["FLEET_DEMO_DIR"] = str(tmp)
        env["PYTHONUNBUFFERED"] = "1"
        self.proc = subprocess.Popen(
            [sys.executable, "scripts/demo.py", *args],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self._q: queue.Queue[str | None] = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.children: dict[int, tuple[int, str]] = {}

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._q.put(line)
        self._q.put(None)

    def wait_for_line(self, predicate: Callable[[str], bool], timeout: float = 120.0) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self._q.get(timeout=0.5)
            except queue.Empty:
                continue
            if line is None:
                break
            self.lines.append(line)
            if predicate(line):
                return line
        raise AssertionError(f"demo did not print the expected line; output so far:\n{self.text}")

    @property
    def text(self) -> str:
        return "".join(self.lines)

    def line(self, label: str) -> str:
        """The summary line that starts with ``label`` (e.g. "dashboard")."""
        return next(ln for ln in self.lines if ln.strip().startswith(label))

    def field(self, label: str) -> str:
        """The first word after ``label`` on its summary line (e.g. "dashboard" -> its URL)."""
        return self.line(label).split()[1]

    def snapshot_children(self) -> None:
        self.children = _descendants(self.proc.pid)

    def interrupt(self, timeout: float = 10.0) -> int:
        """Ctrl-C: the demo must exit within ``timeout`` seconds."""
        self.proc.send_signal(signal.SIGINT)
        return self.proc.wait(timeout)

    def leftovers(self) -> list[str]:
        """Processes the demo started (same pid and start time) or process groups it made, still alive."""
        groups = {pgid for pgid, _start in self.children.values()} - {os.getpgrp()}
        alive = []
        for pid, (_ppid, pgid, start) in _processes().items():
            if (pid in self.children and self.children[pid][1] == start) or pgid in groups:
                with contextlib.suppress(OSError):
                    alive.append(f"{pid}: {Path(f'/proc/{pid}/cmdline').read_text().replace(chr(0), ' ')}")
        return alive

    def kill_everything(self) -> None:
        """Clean-up after a failed test: nothing may outlive it."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        for pgid in {pgid for pgid, _start in self.children.values()} - {os.getpgrp()}:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(pgid, signal.SIGKILL)
        self._reader.join(5)


@contextlib.contextmanager
def run_demo(tmp: Path, *args: str, **fleet_env: str) -> Iterator[Demo]:
    demo = Demo(tmp, *args, **fleet_env)
    try:
        demo.wait_for_line(lambda ln: ln.startswith("Ready."))
        demo.snapshot_children()
        yield demo
    finally:
        demo.kill_everything()


def _stops_cleanly(demo: Demo) -> None:
    assert len(demo.children) >= 5, f"broker + server + 3 robots expected, found {demo.children}"
    assert demo.interrupt(timeout=10) == 0, demo.text
    assert demo.leftovers() == [], "Ctrl-C must stop every process the demo started"


def _listening_on(port: int) -> set[str]:
    """The addresses something listens on at TCP ``port`` (from /proc/net/tcp and tcp6)."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for row in Path(table).read_text().splitlines()[1:]:
            local, state = row.split()[1], row.split()[3]
            address, _, hex_port = local.partition(":")
            if state == "0A" and int(hex_port, 16) == port:  # 0A: LISTEN
                raw = bytes.fromhex(address)
                words = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))  # little-endian words
                found.add(socket.inet_ntop(socket.AF_INET if len(raw) == 4 else socket.AF_INET6, words))
    return found


def _online(base_url: str) -> set[str]:
    return {r["id"] for r in httpx.get(f"{base_url}/api/robots", timeout=10).json() if r["online"]}


@pytest.mark.slow
def test_demo_runs_three_robots_that_move_on_command_and_stops_cleanly(tmp_path: Path) -> None:
    with run_demo(tmp_path, "--port", "0", "--broker-port", "0") as demo:
        assert "[mosquitto" in demo.line("broker")
        url = demo.field("dashboard").rstrip("/")
        # an anonymous broker and a server maybe without authentication: this machine only, unless --lan
        broker_port = int(demo.field("broker").rsplit(":", 1)[1])
        server_port = int(url.rsplit(":", 1)[1])
        assert _listening_on(broker_port) == {"127.0.0.1"} and _listening_on(server_port) == {"127.0.0.1"}
        assert "127.0.0.1 only" in demo.line("listening") and "--lan" in demo.line("listening")
        assert {"snail-1", "snail-2", "snail-3"} <= _online(url)
        with httpx.Client(base_url=url, timeout=10) as c:
            page = c.get("/")
            assert page.status_code == 200 and "Mollusca Fleet" in page.text
            start = c.get("/api/robots/snail-1").json()["position"]
            r = c.post(
                "/api/robots/snail-1/commands?wait=3",
                json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 1.0}},
            )
            assert r.status_code == 200, r.text
            assert r.json()["status"] in ("done", "accepted"), r.text

            def moved() -> bool:
                end = c.get("/api/robots/snail-1").json()["position"]
                return math.hypot(end["x"] - start["x"], end["y"] - start["y"]) > 0.15

            wait_for(moved, 10, what="snail-1 to move")
            # the curl line the demo prints drives a robot too
            curl = next(ln for ln in demo.lines if "curl -X POST" in ln)
            assert f"{url.replace('127.0.0.1', 'localhost')}/api/robots/snail-1/commands?wait=3" in curl
        _stops_cleanly(demo)


@pytest.mark.slow
def test_embedded_broker_and_taken_ports(tmp_path: Path) -> None:
    """Without mosquitto (forced): the amqtt broker carries the same fleet. Ports that are taken are
    replaced by free ones."""
    with socket.socket() as busy_http, socket.socket() as busy_mqtt:
        for s in (busy_http, busy_mqtt):
            s.bind(("0.0.0.0", 0))
            s.listen()
        http_port, mqtt_port = busy_http.getsockname()[1], busy_mqtt.getsockname()[1]
        with run_demo(
            tmp_path,
            "--embedded-broker",
            "--no-browser-hint",
            "--port",
            str(http_port),
            "--broker-port",
            str(mqtt_port),
        ) as demo:
            assert "embedded Python broker" in demo.line("broker")
            assert "Open http" not in demo.text
            url = demo.field("dashboard").rstrip("/")
            broker = demo.field("broker")
            assert not url.endswith(f":{http_port}") and not broker.endswith(f":{mqtt_port}")
            assert {"snail-1", "snail-2", "snail-3"} <= _online(url)
            r = httpx.post(f"{url}/api/robots/snail-2/commands?wait=3", json={"command": "stop"}, timeout=10)
            assert r.status_code == 200 and r.json()["status"] == "done", r.text
            _stops_cleanly(demo)


def test_robots_only_mode_runs_simulated_robots_against_a_given_broker(broker, mqtt_probe, tmp_path: Path):
    """Simulated robots alone, against an existing broker (e.g. to add robots to a base station)."""
    probe = mqtt_probe("fleet/+/status")
    demo = Demo(tmp_path, "--robots-only", broker.url, "--robots", "2")
    try:
        demo.wait_for_line(lambda ln: "Ready." in ln, timeout=60)
        for rid in ("snail-1", "snail-2"):
            probe.wait(lambda m, rid=rid: m.topic == f"fleet/{rid}/status" and b'"online":true' in m.payload, 20)
        demo.snapshot_children()
        assert len(demo.children) == 2
        assert demo.interrupt(timeout=10) == 0
        assert demo.leftovers() == []
    finally:
        demo.kill_everything()


@pytest.mark.slow
def test_demo_with_auth_prints_a_one_time_admin_password_that_logs_in(tmp_path: Path) -> None:
    """FLEET_AUTH=on: the summary names a dashboard admin and its password; the login page takes it, and
    the next start prints a new password that replaces the old one (demo state is kept between runs)."""
    passwords = []
    for _ in range(2):
        with run_demo(tmp_path, "--port", "0", "--broker-port", "0", "--robots", "1", FLEET_AUTH="on") as demo:
            url = demo.field("dashboard").rstrip("/")
            words = demo.line("log in as").split()
            assert words[3] == "admin" and words[4] == "/", words
            password = words[5]
            with httpx.Client(base_url=url, timeout=10) as c:
                assert c.get("/api/robots").status_code == 401  # authentication really is on
                for old in passwords:
                    assert c.post("/api/auth/login", json={"username": "admin", "password": old}).status_code == 401
                r = c.post("/api/auth/login", json={"username": "admin", "password": password})
                assert r.status_code == 200 and r.json()["role"] == "admin", r.text
                assert c.get("/api/users").status_code == 200  # the session cookie is an admin's
            passwords.append(password)
            assert demo.interrupt(timeout=10) == 0, demo.text
    assert passwords[0] != passwords[1]
