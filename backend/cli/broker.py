"""``fleet-server robots add|remove|forget``, ``broker-user``, ``broker-init`` and ``legacy-sentinel``: the
broker's side of the fleet (accounts, the ACL, the sentinel beside it), and forgetting a robot through the
running server."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from backend.core.config import Settings


def _password_file(settings: Settings, given: Path | None) -> Path:
    return given or settings.mqtt_password_file


def _forget_robot(settings: Settings, args: argparse.Namespace) -> int:
    """The running server forgets the robot (it holds the registry): DELETE /api/robots/{id} as admin."""
    from backend.cli.server_api import admin_request

    done = admin_request(
        settings, args, "robots forget", "DELETE", f"/api/robots/{args.robot_id}", params={"telemetry": args.telemetry}
    )
    if done is None:
        return 1
    kept = "telemetry kept" if done["telemetry"] == "keep" else f"{done['rows_deleted']} telemetry rows deleted"
    print(
        f"forgot robot {done['robot_id']} ({kept}); its broker credentials are unchanged "
        "(`fleet-server robots remove` removes them)"
    )
    return 0


def robots(settings: Settings, args: argparse.Namespace) -> int:
    from backend.core import broker_auth

    if args.action == "forget":
        return _forget_robot(settings, args)
    if args.action in ("legacy-add", "legacy-remove"):
        from backend.cli.server_api import legacy_robot

        return legacy_robot(settings, args)

    path = _password_file(settings, args.password_file)
    try:
        broker_auth.check_robot_username(args.robot_id)
    except ValueError as exc:
        print(f"fleet-server robots: {exc}", file=sys.stderr)
        return 1
    if args.action == "remove":
        if not broker_auth.remove_broker_user(path, args.robot_id):
            print(f"fleet-server robots: {args.robot_id} not in {path}", file=sys.stderr)
            return 1
        print(f"removed {args.robot_id} from {path}; reload the broker (SIGHUP) to apply")
        return 0
    if not args.print_password:  # the default: a one-line enrolment for the Pi, no password shown (issue 29 #3)
        from backend.cli.enrol import add_with_enrolment

        return add_with_enrolment(settings, args, path)
    password = broker_auth.new_broker_password()
    broker_auth.set_broker_password(path, args.robot_id, password)
    broker = args.broker or "mqtt://BROKER-HOST:1883"
    print(
        f"# broker credentials for robot {args.robot_id} written to {path}\n"
        "# reload the broker to apply: docker compose kill -s HUP mosquitto  (or systemctl reload fleet-mosquitto)\n"
        "# agent config (TOML, e.g. /etc/fleet-agent/agent.toml; keep it mode 0600):\n"
        f'robot_id = "{args.robot_id}"\n'
        f'broker = "{broker}"\n'
        f'username = "{args.robot_id}"\n'
        f'password = "{password}"\n'
        "# or as environment variables:\n"
        f"# FLEET_AGENT_ROBOT_ID={args.robot_id} FLEET_AGENT_BROKER={broker} "
        f"FLEET_AGENT_USERNAME={args.robot_id} FLEET_AGENT_PASSWORD={password}"
    )
    return 0


def broker_user(settings: Settings, args: argparse.Namespace) -> int:
    from backend.core import broker_auth

    path = _password_file(settings, args.password_file)
    password = broker_auth.new_broker_password()
    try:
        broker_auth.set_broker_password(path, args.username, password)
    except ValueError as exc:
        print(f"fleet-server broker-user: {exc}", file=sys.stderr)
        return 1
    host = args.broker_host
    print(
        f"# broker credentials for {args.username} written to {path}; reload the broker to apply\n"
        f"FLEET_MQTT_URL=mqtt://{args.username}:{password}@{host}"
    )
    return 0


def broker_init(settings: Settings, args: argparse.Namespace) -> int:
    """Compose's one-shot service before Mosquitto: accounts from .env, the shipped ACL."""
    from backend.core import broker_auth

    sim_robots = [r.strip() for r in args.sim_robots.split(",") if r.strip()] if args.sim_robots else []
    try:
        done = broker_auth.init_broker_auth(
            args.auth_dir,
            settings.mqtt_username,
            settings.mqtt_password.get_secret_value(),
            args.acl_template,
            sim_robots,
            os.environ.get("FLEET_SIM_ROBOT_PASSWORD", ""),
        )
    except (ValueError, OSError) as exc:
        print(f"fleet-server broker-init: {exc}", file=sys.stderr)
        return 2
    for line in done:
        print(line)
    return 0


def legacy_sentinel(settings: Settings) -> int:
    import signal
    import threading

    from backend.comms.client_id import sentinel_client_id
    from backend.comms.legacy_sentinel import LegacySentinel
    from fleet_protocol import Topics

    sentinel = LegacySentinel(
        mqtt_url=settings.mqtt_url,
        topics=Topics(settings.topic_prefix),
        credentials=settings.mqtt_credentials,
        # FLEET_MQTT_CLIENT_ID plus a fresh secret suffix: never the server's id, even from a shared env file
        # (the broker would drop one of the two), and not guessable by another account (comms/client_id.py)
        client_id=sentinel_client_id(settings.mqtt_client_id),
    )
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    sentinel.start()
    print(
        f"legacy sentinel watching {Topics(settings.topic_prefix).heartbeat()} on {settings.mqtt_url_redacted}",
        flush=True,
    )
    try:
        done.wait()
    except KeyboardInterrupt:
        pass
    finally:
        sentinel.stop()
    return 0
