"""``fleet-agent estop [--release]``: the fleet e-stop straight to the broker, no server needed.

It publishes exactly what the server's e-stop publishes (the retained ``{prefix}/estop``, fleet_protocol
EStop) with an account of its own, ``fleet-estop``, which the shipped ACL allows to write that topic and
nothing else. ``fleet-agent estop-button`` runs it from a push-button on the base station's GPIO
(deploy/systemd/fleet-estop-button.service). Exit status: 0 confirmed, 1 not confirmed, 2 bad arguments.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import socket
import sys
import threading
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from fleet_protocol import DEFAULT_PREFIX, QOS_ESTOP, EStop, Topics, dumps, now

log = logging.getLogger("fleet-estop")

ESTOP_USERNAME = "fleet-estop"
DEFAULT_BROKER = "mqtt://127.0.0.1:1883"


def _add_broker_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--broker",
        default=os.environ.get("FLEET_ESTOP_BROKER", DEFAULT_BROKER),
        help=f"mqtt://HOST:PORT or mqtts:// (env FLEET_ESTOP_BROKER; default {DEFAULT_BROKER})",
    )
    p.add_argument(
        "--username",
        default=os.environ.get("FLEET_ESTOP_USERNAME", ESTOP_USERNAME),
        help=f"broker account (default {ESTOP_USERNAME}; '' = anonymous)",
    )
    p.add_argument(
        "--password-file",
        type=Path,
        default=None,
        help="file holding the account's password (else env FLEET_ESTOP_PASSWORD)",
    )
    p.add_argument("--tls-ca", default=None, help="CA certificate of the broker's TLS listener")
    p.add_argument("--prefix", default=os.environ.get("FLEET_ESTOP_PREFIX", DEFAULT_PREFIX), help="topic prefix")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the broker (default 5)")


def _engager(args: argparse.Namespace) -> Callable[[bool, str, str], str | None]:
    """A function (engaged, reason, source) -> None when the broker delivered the e-stop, else the problem."""
    from robot_agent.config import parse_broker_url
    from robot_agent.link.oneshot import BrokerLogin, publish_confirmed

    host, port = parse_broker_url(args.broker)
    if args.password_file is not None:
        password: str | None = args.password_file.read_text().strip()
    else:
        password = os.environ.get("FLEET_ESTOP_PASSWORD") or None
    login = BrokerLogin(
        host,
        port,
        args.username or None,
        password,
        tls=args.broker.lower().startswith(("mqtts://", "ssl://")),
        tls_ca=args.tls_ca,
    )
    topic = Topics(args.prefix).estop()

    def send(engaged: bool, reason: str, source: str) -> str | None:
        msg = EStop(ts=now(), id=str(uuid.uuid4()), engaged=engaged, reason=reason[:500], source=source[:120])
        return publish_confirmed(login, topic, dumps(msg), qos=QOS_ESTOP, retain=True, timeout_s=args.timeout)

    return send


def main_estop(argv: Sequence[str]) -> int:
    p = argparse.ArgumentParser(
        prog="fleet-agent estop", description="Engage (or --release) the fleet e-stop directly on the broker."
    )
    p.add_argument("--release", action="store_true", help="release the e-stop instead of engaging it")
    p.add_argument("--reason", default="", help="shown on the dashboard and in the event log")
    p.add_argument(
        "--source",
        default=f"fleet-agent estop@{socket.gethostname()}"[:120],
        help="who engaged it, shown with the e-stop (default fleet-agent estop@HOSTNAME)",
    )
    _add_broker_args(p)
    args = p.parse_args(list(argv))
    try:
        send = _engager(args)
    except (ValueError, OSError) as exc:
        print(f"fleet-agent estop: {exc}", file=sys.stderr)
        return 2
    problem = send(not args.release, args.reason, args.source)
    what = "released" if args.release else "ENGAGED"
    if problem is not None:
        hint = ""
        if args.username and args.password_file is None and not os.environ.get("FLEET_ESTOP_PASSWORD"):
            hint = " (no password given: set FLEET_ESTOP_PASSWORD or --password-file)"
        print(f"fleet-agent estop: e-stop NOT {what.lower()}: {problem}{hint}", file=sys.stderr)
        return 1
    print(f"fleet e-stop {what} on {args.broker}")
    return 0


def run_button(button: Any, engage: Callable[[], str | None], stop: threading.Event, retry_s: float = 1.0) -> None:
    """Engage the e-stop on every press of ``button`` (a gpiozero Button), retrying until the broker confirms
    it; returns when ``stop`` is set."""
    pressed = threading.Event()
    button.when_pressed = pressed.set
    while not stop.is_set():
        if not pressed.wait(0.2):
            continue
        pressed.clear()
        log.warning("e-stop button pressed")
        while not stop.is_set():
            problem = engage()
            if problem is None:
                log.warning("fleet e-stop ENGAGED")
                break
            log.error("e-stop not confirmed (%s); retrying", problem)
            stop.wait(retry_s)


def main_button(argv: Sequence[str]) -> int:
    p = argparse.ArgumentParser(
        prog="fleet-agent estop-button",
        description="Engage the fleet e-stop when a push-button on a GPIO pin is pressed.",
    )
    p.add_argument("--pin", type=int, required=True, help="BCM pin of the button (to ground; internal pull-up)")
    p.add_argument("--active-high", action="store_true", help="the button pulls the pin high (external pull-down)")
    p.add_argument("--bounce", type=float, default=0.05, help="debounce seconds (default 0.05)")
    p.add_argument("--reason", default="base-station e-stop button")
    _add_broker_args(p)
    args = p.parse_args(list(argv))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        send = _engager(args)
        from gpiozero import Button

        button = Button(args.pin, pull_up=not args.active_high, bounce_time=args.bounce)
    except Exception as exc:
        print(f"fleet-agent estop-button: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    log.info("watching GPIO %d: a press engages the fleet e-stop on %s", args.pin, args.broker)
    source = f"button@{socket.gethostname()}"[:120]
    try:
        run_button(button, lambda: send(True, args.reason, source), stop)
    finally:
        button.close()
    return 0
