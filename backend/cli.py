"""``fleet-server``: ``serve`` (default), ``db upgrade|current``, ``backup``, ``restore``, ``export``,
``create-admin``, ``users add|list|remove``, ``robots add|remove``, ``broker-user``, ``broker-init``."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from datetime import UTC
from pathlib import Path
from typing import TYPE_CHECKING

from backend.core.config import Settings
from backend.core.logging import setup_logging

if TYPE_CHECKING:
    from sqlalchemy import Engine

    from backend.services.auth import AuthService

log = logging.getLogger("backend")


def _serve(settings: Settings, host: str, port: int) -> int:
    import uvicorn

    from backend.main import create_app

    config = uvicorn.Config(
        create_app(settings),
        host=host,
        port=port,
        log_config=None,
        log_level=settings.log_level.lower(),
        ws="websockets-sansio",
        # no permessage-deflate: compressing every live frame for every client on the event loop cost
        # more than a tenth of the server's CPU at 100 robots x 20 Hz, and the lab network has bandwidth
        ws_per_message_deflate=False,
        lifespan="on",
    )
    uvicorn.Server(config).run()
    return 0


def _db(settings: Settings, action: str, revision: str | None = None) -> int:
    from backend.store.db import create_db_engine, current_revision, downgrade_to, upgrade_to_head

    if action == "downgrade" and not revision:
        print("fleet-server db downgrade: give the revision to go back to (e.g. 0002; base = empty)",
              file=sys.stderr)
        return 2
    engine = create_db_engine(settings)
    try:
        if action == "upgrade":
            upgrade_to_head(engine)
        elif action == "downgrade":
            assert revision is not None
            downgrade_to(engine, revision)
        print(current_revision(engine) or "(empty database)")
    finally:
        engine.dispose()
    return 0


def _auth_service(settings: Settings) -> tuple[AuthService, Engine]:
    from backend.services.auth import AuthService
    from backend.store.db import create_db_engine, upgrade_to_head

    engine = create_db_engine(settings)
    upgrade_to_head(engine)
    return AuthService(settings, engine), engine


def _create_admin(settings: Settings, name: str) -> int:
    from backend.services.auth import TokenCreate

    auth, engine = _auth_service(settings)
    try:
        created = auth.create_token(TokenCreate(name=name, role="admin"), "fleet-server create-admin")
    finally:
        engine.dispose()
    print(f"admin API token {created.id} ({name}); shown only now, store it safely:", file=sys.stderr)
    print(created.token)
    return 0


def _read_password(args: argparse.Namespace) -> str:
    import getpass

    if args.password_stdin or not sys.stdin.isatty():
        return sys.stdin.readline().rstrip("\r\n")
    first = getpass.getpass(f"password for {args.name}: ")
    if getpass.getpass("again: ") != first:
        raise ValueError("the passwords differ")
    return first


def _users(settings: Settings, args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from backend.services.auth import AuthError

    try:
        password = _read_password(args) if args.action == "add" else ""
    except ValueError as exc:
        print(f"fleet-server users: {exc}", file=sys.stderr)
        return 1
    auth, engine = _auth_service(settings)
    try:
        if args.action == "add":
            user = auth.set_user(args.name, password, args.role)
            print(f"user {user.username}: role {user.role}")
        elif args.action == "remove":
            auth.delete_user(args.name)
            print(f"user {args.name} removed")
        else:
            for u in auth.list_users():
                print("\t".join([u.username, u.role, *(["disabled"] if u.disabled else [])]))
    except ValidationError as exc:
        errors = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors(include_input=False))
        print(f"fleet-server users: {errors}", file=sys.stderr)
        return 1
    except AuthError as exc:
        print(f"fleet-server users: {exc.detail}", file=sys.stderr)
        return 1
    finally:
        engine.dispose()
    return 0


def _password_file(settings: Settings, given: Path | None) -> Path:
    return given or settings.mqtt_password_file


def _robots(settings: Settings, args: argparse.Namespace) -> int:
    from backend.core import broker_auth

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


def _broker_user(settings: Settings, args: argparse.Namespace) -> int:
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


def _when(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        from datetime import datetime

        dt = datetime.fromisoformat(text.replace("Z", "+00:00"))
        return (dt if dt.tzinfo else dt.replace(tzinfo=UTC)).timestamp()


def _ops(settings: Settings, args: argparse.Namespace) -> int:
    import time

    from backend import ops

    try:
        if args.cmd == "backup":
            print(ops.backup(settings, args.path))
        elif args.cmd == "restore":
            print(ops.restore(settings, args.path, force=args.force))
        else:
            end = _when(args.end) if args.end else time.time()
            print(ops.export_run(settings, args.path, _when(args.start), end))
    except (ops.OpsError, ValueError) as exc:
        print(f"fleet-server {args.cmd}: {exc}", file=sys.stderr)
        return 1
    return 0


def _broker_init(settings: Settings, args: argparse.Namespace) -> int:
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


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fleet-server", description="Mollusca Fleet server")
    sub = p.add_subparsers(dest="cmd")
    serve = sub.add_parser("serve", help="run the server (default)")
    serve.add_argument("--host", default="0.0.0.0")
    serve.add_argument("--port", type=int, default=8000)
    db = sub.add_parser("db", help="database schema (Alembic)")
    db.add_argument("action", choices=["upgrade", "downgrade", "current"])
    db.add_argument("revision", nargs="?", default=None, help="downgrade: the revision to go back to")
    bk = sub.add_parser("backup", help="consistent copy of the database (safe while the server runs)")
    bk.add_argument("path", type=Path)
    rs = sub.add_parser("restore", help="replace the database with a backup (stop the server first)")
    rs.add_argument("path", type=Path)
    rs.add_argument("--force", action="store_true", help="replace an existing database")
    ex = sub.add_parser("export", help="zip of a time range: telemetry CSV, commands, events, robots")
    ex.add_argument("path", type=Path)
    ex.add_argument("--start", required=True, help="ISO 8601 or epoch seconds")
    ex.add_argument("--end", default=None, help="ISO 8601 or epoch seconds (default now)")
    ca = sub.add_parser("create-admin", help="create an admin API token and print it (once)")
    ca.add_argument("--name", default="admin", help="label shown in the token list")
    us = sub.add_parser("users", help="dashboard users: add (or reset password/role), list, remove")
    us.add_argument("action", choices=["add", "list", "remove"])
    us.add_argument("name", nargs="?", default="")
    us.add_argument("--role", choices=["viewer", "operator", "admin"], default="viewer")
    us.add_argument("--password-stdin", action="store_true", help="read the password from stdin")
    rb = sub.add_parser("robots", help="a robot's broker credentials (Mosquitto password file)")
    rb.add_argument("action", choices=["add", "remove"])
    rb.add_argument("robot_id")
    rb.add_argument("--password-file", type=Path, default=None,
                    help="Mosquitto password file (default FLEET_MQTT_PASSWORD_FILE)")
    rb.add_argument("--broker", default=None, help="broker URL for the printed agent config")
    bu = sub.add_parser("broker-user", help="broker credentials for the server (or another client)")
    bu.add_argument("username", nargs="?", default="fleet-server")
    bu.add_argument("--password-file", type=Path, default=None)
    bu.add_argument("--broker-host", default="mosquitto:1883", help="host:port for the printed FLEET_MQTT_URL")
    bi = sub.add_parser("broker-init", help="broker password file + ACL from the environment (compose)")
    bi.add_argument("auth_dir", type=Path, help="directory Mosquitto reads passwd and acl from")
    bi.add_argument("--acl-template", type=Path, default=Path(__file__).resolve().parents[1] / "deploy"
                    / "mosquitto" / "acl.example", help="ACL installed when the directory has none")
    bi.add_argument("--sim-robots", default="", help="comma-separated ids given FLEET_SIM_ROBOT_PASSWORD")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        settings = Settings()
    except Exception as exc:  # pydantic ValidationError: bad configuration is a clean exit, not a trace
        errors = getattr(exc, "errors", None)
        if callable(errors):  # never echo the input: it holds the secrets
            text = "; ".join(str(e.get("msg", e)) for e in errors(include_input=False, include_url=False))
        else:
            text = str(exc)
        print(f"fleet-server: invalid configuration: {text}", file=sys.stderr)
        return 2
    setup_logging(settings.log_level, settings.log_format, queued=args.cmd == "serve")
    if args.cmd == "db":
        return _db(settings, args.action, args.revision)
    if args.cmd == "create-admin":
        return _create_admin(settings, args.name)
    if args.cmd == "users":
        if args.action != "list" and not args.name:
            print("fleet-server users: a user name is required", file=sys.stderr)
            return 2
        return _users(settings, args)
    if args.cmd == "robots":
        return _robots(settings, args)
    if args.cmd == "broker-user":
        return _broker_user(settings, args)
    if args.cmd == "broker-init":
        return _broker_init(settings, args)
    if args.cmd in ("backup", "restore", "export"):
        return _ops(settings, args)
    return _serve(settings, getattr(args, "host", "0.0.0.0"), getattr(args, "port", 8000))


if __name__ == "__main__":
    sys.exit(main())
