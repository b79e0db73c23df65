"""``fleet-server robots add ID``: the robot's broker account and a one-line enrolment for its Pi (issue 29 #3).

The password goes into the Mosquitto password file (hashed) and, sealed with a single-use token, into the
server's database; the CLI prints only ``install-pi.sh --enrol SERVER TOKEN``. The robot exchanges the token
once (``POST /api/enrol``) for its password and the base station's pin, so no password is typed on a command
line or shown on a screen. ``--print-password`` prints the old hand-made agent config instead.
"""

from __future__ import annotations

import argparse
import socket
import sys
import time
from pathlib import Path

from backend.core.config import Settings
from backend.core.enrolment import MAX_TTL_S

#: what the robot runs, from a checkout of this repository on the Pi
INSTALL = "sudo ./robot_agent/deploy/install-pi.sh"
MAX_CA_BYTES = 65536


def _lan_address() -> str:
    """The address the default route leaves from: what a robot on the LAN most likely reaches us at."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # TEST-NET: no packet is sent for a UDP connect
            return str(s.getsockname()[0])
        except OSError:
            return "127.0.0.1"


def _read_ca(path: Path | None) -> str | None:
    if path is None:
        return None
    text = path.read_text()
    if "-----BEGIN CERTIFICATE-----" not in text or len(text) > MAX_CA_BYTES:
        raise ValueError(f"{path} is not a PEM CA certificate (at most {MAX_CA_BYTES} bytes)")
    return text


def _check_broker(url: str | None) -> None:
    if url is None:
        return
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname or parts.username or parts.password:
        raise ValueError(f"--broker must be mqtt://HOST:PORT or mqtts://HOST:PORT without credentials, not {url!r}")


def add_with_enrolment(settings: Settings, args: argparse.Namespace, password_file: Path) -> int:
    """The broker account in ``password_file`` and its enrolment in the server's database; prints the line
    for the Pi on stdout (everything else on stderr). The database is checked first: a refused target
    changes nothing."""
    from backend.cli.accounts import _audit
    from backend.core import broker_auth
    from backend.store.db import create_db_engine, upgrade_to_head
    from backend.store.enrolments import create_enrolment
    from backend.store.target import TargetDatabaseError, check_named, check_schema, describe_database

    ttl_s = args.enrol_ttl * 60.0
    if not 60 <= ttl_s <= MAX_TTL_S:
        print(f"fleet-server robots: --enrol-ttl is 1 to {MAX_TTL_S // 60} minutes", file=sys.stderr)
        return 2
    try:
        _check_broker(args.broker)
        tls_ca = _read_ca(args.tls_ca)
        check_named(settings, force=args.force)
    except (ValueError, OSError, TargetDatabaseError) as exc:
        print(f"fleet-server robots add: {exc}", file=sys.stderr)
        return 1
    engine = create_db_engine(settings)
    try:
        try:
            check_schema(settings, engine, force=args.force)
        except TargetDatabaseError as exc:
            print(f"fleet-server robots add: {exc}", file=sys.stderr)
            return 1
        upgrade_to_head(engine)
        password = broker_auth.new_broker_password()
        broker_auth.set_broker_password(password_file, args.robot_id, password)
        now = time.time()
        token = create_enrolment(
            engine, args.robot_id, password, args.broker, tls_ca, ttl_s, "fleet-server robots add", now
        )
        _audit(engine, "robot_enrolment_create", {"robot": args.robot_id, "expires_at": now + ttl_s})
    finally:
        engine.dispose()
    server = (args.enrol_url or f"http://{_lan_address()}:8000").rstrip("/")
    expires = time.strftime("%H:%M UTC", time.gmtime(now + ttl_s))
    print(
        f"# broker account {args.robot_id} written to {password_file}; reload the broker to apply: "
        "docker compose kill -s HUP mosquitto  (or systemctl reload fleet-mosquitto)\n"
        f"# enrolment stored in {describe_database(settings)}; on the robot, from a checkout of this repository, "
        f"before {expires} (it works once; the password never appears):",
        file=sys.stderr,
    )
    if args.enrol_url is None:
        print(f"# (the robot must reach this server at {server}: --enrol-url sets that address)", file=sys.stderr)
    print(f"{INSTALL} --enrol {server} {token}")
    return 0
