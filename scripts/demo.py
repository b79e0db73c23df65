"""`make demo`: a broker, the server and simulated robots on this machine, stopped together by Ctrl-C.

Broker: the `mosquitto` binary when installed (on 1883, or a free port when 1883 is taken), otherwise an
embedded Python broker (amqtt, from the `demo` extra) so the demo still runs. Either broker is checked with
a real MQTT round trip (connect, retained message, QoS 1) before anything else starts. Server:
http://localhost:8000 (or a free port). Robots: N simulated agents (default 3) named snail-1..N. State and
logs go to .demo/ (FLEET_DEMO_DIR). FLEET_AUTH / FLEET_ADMIN_TOKEN from the environment are passed to the
server (the demo sets FLEET_AUTH=off unless it is given).

Port options take 0 for "any free port" (the tests use that). Exit status: 0 after Ctrl-C / SIGTERM,
1 when something failed to start or died.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import math
import os
import secrets
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

# scripts/demo_broker.py, beside this file
from demo_broker import broker_data_dir, demo_mosquitto_conf, mosquitto_binary, mqtt_round_trip
from demo_console import first_admin, summary  # scripts/ is on sys.path when run as a script

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
DEMO = Path(os.environ.get("FLEET_DEMO_DIR", str(ROOT / ".demo")))  # state and logs


class Interrupted(Exception):
    """Ctrl-C / SIGTERM arrived: stop everything and exit 0."""


# --------------------------------------------------------------------------------------------------
# ports
# --------------------------------------------------------------------------------------------------


def port_free(port: int) -> bool:
    """Nothing listens on ``port`` on any IPv4 interface (the demo's services listen on all of them)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("0.0.0.0", 0))
        return int(s.getsockname()[1])


def pick_port(wanted: int) -> int:
    """``wanted`` if free, else any free port; 0 means any free port."""
    if wanted and port_free(wanted):
        return wanted
    return free_port()


def lan_address() -> str | None:
    """The address other machines reach this one at (the one the default route leaves from), if any."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # TEST-NET-1: a UDP connect sends no packet
            addr = str(s.getsockname()[0])
        except OSError:
            return None
    return None if addr.startswith("127.") else addr


# --------------------------------------------------------------------------------------------------
# child processes
# --------------------------------------------------------------------------------------------------


def _die_with_parent() -> None:
    """In the child before exec: get SIGTERM if the demo itself dies without cleaning up (e.g. SIGKILL)."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class Stack:
    """Child processes, each in its own session (process group), stopped in stages: robots, server, broker."""

    def __init__(self, logdir: Path) -> None:
        self.logdir = logdir
        self.logdir.mkdir(parents=True, exist_ok=True)
        self.procs: list[tuple[str, int, subprocess.Popen[bytes]]] = []  # (name, stage, process)

    def start(
        self, name: str, argv: list[str], env: dict[str, str] | None = None, stage: int = 0
    ) -> subprocess.Popen[bytes]:
        with open(self.logdir / f"{name}.log", "wb") as log:
            proc = subprocess.Popen(
                argv,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                cwd=ROOT,
                env=env,
                start_new_session=True,
                preexec_fn=_die_with_parent,
            )
        self.procs.append((name, stage, proc))
        return proc

    def check(self) -> None:
        for name, _stage, proc in self.procs:
            if proc.poll() is not None:
                tail = (self.logdir / f"{name}.log").read_text(errors="replace")[-3000:]
                raise RuntimeError(f"{name} exited with status {proc.returncode}; end of its log:\n{tail}")

    @staticmethod
    def _group_alive(pgid: int) -> bool:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True

    def _stop_stage(self, procs: list[subprocess.Popen[bytes]], timeout: float) -> None:
        for proc in procs:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for proc in procs:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(max(0.05, deadline - time.monotonic()))
        for proc in procs:  # the leader and anything it left in its group
            while self._group_alive(proc.pid) and time.monotonic() < deadline:
                time.sleep(0.05)
            if proc.poll() is None or self._group_alive(proc.pid):
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(3)

    def stop(self) -> None:
        """Robots first (they publish their offline status), then the server, then the broker."""
        timeouts = {2: 4.0, 1: 4.0, 0: 1.5}
        for stage in sorted({s for _n, s, _p in self.procs}, reverse=True):
            self._stop_stage([p for _n, s, p in self.procs if s == stage], timeouts.get(stage, 3.0))


# --------------------------------------------------------------------------------------------------
# checks
# --------------------------------------------------------------------------------------------------


class Waiter:
    def __init__(self, stack: Stack, stopping: threading.Event) -> None:
        self.stack = stack
        self.stopping = stopping

    def until(self, what: str, check: Callable[[], Any], timeout: float) -> Any:
        deadline = time.monotonic() + timeout
        last: Exception | None = None
        while time.monotonic() < deadline:
            if self.stopping.is_set():
                raise Interrupted
            self.stack.check()
            try:
                value = check()
                if value:
                    return value
            except (OSError, ValueError, KeyError, TypeError, urllib.error.URLError) as exc:
                last = exc
            self.stopping.wait(0.2)
        raise RuntimeError(f"timed out after {timeout:.0f}s waiting for {what} (last error: {last!r})")


def get_json(url: str, token: str | None = None) -> Any:
    req = urllib.request.Request(url, headers={"Authorization": f"Bearer {token}"} if token else {})
    with urllib.request.urlopen(req, timeout=2) as r:
        return json.loads(r.read())


# --------------------------------------------------------------------------------------------------
# the pieces
# --------------------------------------------------------------------------------------------------


EMBEDDED_KIND = "embedded Python broker (amqtt; install mosquitto for a lab)"


def start_broker(stack: Stack, wait: Waiter, port: int, embedded: bool, host: str) -> str:
    mosquitto = None if embedded else mosquitto_binary()
    if mosquitto:
        conf = DEMO / "mosquitto.conf"
        conf.write_text(demo_mosquitto_conf(port, broker_data_dir(DEMO), host))
        stack.start("mosquitto", [mosquitto, "-c", str(conf)])
        kind = f"mosquitto ({mosquitto})"
    else:
        stack.start(
            "broker",
            [
                str(BIN / "python"),
                str(ROOT / "scripts" / "embedded_broker.py"),
                "--host",
                host,
                "--port",
                str(port),
            ],
        )
        kind = EMBEDDED_KIND
    wait.until(f"the broker on port {port} (connect, retained message, QoS 1)", lambda: mqtt_round_trip(port), 30)
    return kind


def robot_poses(count: int) -> list[tuple[str, str]]:
    """``count`` robots on a circle in the pool, each facing along it: (id, "X,Y,YAW")."""
    out = []
    for i in range(count):
        angle = 2 * math.pi * i / max(1, count)
        yaw = math.atan2(math.cos(angle), -math.sin(angle))  # angle + 90°, in (-pi, pi]
        pose = f"{1.2 * math.cos(angle):.2f},{1.2 * math.sin(angle):.2f},{yaw:.2f}"
        out.append((f"snail-{i + 1}", pose))
    return out


def start_robots(stack: Stack, broker_url: str, count: int, camera: bool, env: dict[str, str]) -> list[str]:
    ids = []
    for rid, pose in robot_poses(count):
        extra = ["--camera"] if camera else []
        # --disturbances: the honest simulator (water current, motor noise, Lighthouse noise, latency)
        stack.start(
            rid,
            [
                str(BIN / "fleet-agent"),
                "--robot-id",
                rid,
                "--broker",
                broker_url,
                "--simulate",
                "--disturbances",
                f"--start-pose={pose}",
                *extra,
            ],
            env,
            stage=2,
        )
        ids.append(rid)
    return ids


def child_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("FLEET_AGENT_")}
    env["PYTHONUNBUFFERED"] = "1"
    return env


# --------------------------------------------------------------------------------------------------


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--robots", type=int, default=3, help="number of simulated robots (default 3)")
    p.add_argument("--port", type=int, default=8000, help="server port (default 8000; 0 = any free port)")
    p.add_argument("--broker-port", type=int, default=1883, help="broker port (default 1883; 0 = any free port)")
    p.add_argument("--embedded-broker", action="store_true", help="use the Python broker even if mosquitto exists")
    p.add_argument("--camera", action="store_true", help="robots also stream a simulated camera + AprilTags")
    p.add_argument("--lan", action="store_true", help="listen on every interface (default: this machine only)")
    p.add_argument("--no-browser-hint", action="store_true", help="do not print the 'open a browser' line")
    p.add_argument(
        "--robots-only",
        metavar="BROKER_URL",
        help="only run the simulated robots against this broker (e.g. a base station's)",
    )
    args = p.parse_args(argv)
    if not 0 <= args.robots <= 100:
        p.error("--robots must be between 0 and 100")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    missing = [name for name in ("fleet-server", "fleet-agent") if not (BIN / name).exists()]
    if missing:
        print(
            f"demo: {', '.join(missing)} not found next to {sys.executable}: run `make demo`, or this script "
            "with the Python of the venv the package is installed in (.venv/bin/python)",
            file=sys.stderr,
        )
        return 1
    stopping = threading.Event()

    def on_signal(_signum: int, _frame: object) -> None:
        stopping.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)

    stack = Stack(DEMO / "logs")
    wait = Waiter(stack, stopping)
    try:
        if args.robots_only:
            ids = start_robots(stack, args.robots_only, args.robots, args.camera, child_env())
            print(f"{len(ids)} simulated robots on {args.robots_only}: {', '.join(ids)}. Ready.", flush=True)
        else:
            broker_port = pick_port(args.broker_port)
            host = "0.0.0.0" if args.lan else "127.0.0.1"  # an anonymous broker, maybe auth off: not on the LAN
            broker_kind = start_broker(stack, wait, broker_port, args.embedded_broker, host)
            broker_url = f"mqtt://127.0.0.1:{broker_port}"

            port = pick_port(args.port)
            env = child_env()
            env.setdefault("FLEET_AUTH", "off")
            env.update(FLEET_MQTT_URL=broker_url, FLEET_DATABASE_URL=f"sqlite:///{DEMO / 'fleet.db'}")
            if broker_kind == EMBEDDED_KIND:
                env["FLEET_MQTT_PROTOCOL"] = "3.1.1"  # amqtt speaks MQTT 3.1.1 only
            token: str | None = None
            token_shown = ""
            if env["FLEET_AUTH"].strip().lower() not in ("off", "0", "false", "no", "n", "f"):
                # authentication on: the admin token given, or a fresh one printed in the summary
                token = env.get("FLEET_ADMIN_TOKEN") or ""
                token_shown = "$FLEET_ADMIN_TOKEN" if token else ""
                if not token:
                    token = token_shown = secrets.token_urlsafe(32)
                env["FLEET_ADMIN_TOKEN"] = token
                env.setdefault("FLEET_SECRET_KEY", secrets.token_urlsafe(32))
            stack.start(
                "server", [str(BIN / "fleet-server"), "serve", "--host", host, "--port", str(port)], env, stage=1
            )
            # beside the broker: stops old-framework robots when the server goes silent (docs/safety.md)
            stack.start(
                "legacy-sentinel",
                [str(BIN / "fleet-server"), "legacy-sentinel"],
                {**env, "FLEET_MQTT_CLIENT_ID": "legacy-sentinel"},
                stage=1,
            )
            base = f"http://127.0.0.1:{port}"
            wait.until(
                "the server (GET /api/health: mqtt connected)",
                lambda: get_json(f"{base}/api/health")["mqtt"]["connected"] is True,
                60,
            )

            ids = start_robots(stack, broker_url, args.robots, args.camera, env)

            def all_online() -> bool:
                online = {r["id"] for r in get_json(f"{base}/api/robots", token) if r["online"]}
                return set(ids) <= online

            wait.until(f"{len(ids)} robots online", all_online, 60)
            admin = first_admin(base, token) if token else None
            print(
                summary(
                    port,
                    broker_url,
                    broker_kind,
                    ids,
                    token_shown,
                    not args.no_browser_hint,
                    admin,
                    lan_address() if args.lan else None,
                    DEMO / "logs",
                ),
                flush=True,
            )
        while not stopping.is_set():
            stack.check()
            stopping.wait(0.3)
        raise Interrupted
    except Interrupted:
        print("stopping…", flush=True)
        return 0
    except RuntimeError as exc:
        print(f"demo failed: {exc}", file=sys.stderr, flush=True)
        return 1
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut the clean-up short
        stack.stop()


if __name__ == "__main__":
    sys.exit(main())
