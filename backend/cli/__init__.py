"""``fleet-server``: ``serve`` (default), ``db upgrade|current``, ``backup``, ``restore``, ``export``,
``create-admin``, ``users add|list|remove``, ``robots add|remove|forget``, ``broker-user``, ``broker-init``,
``legacy-sentinel``. Accounts are in ``accounts.py``, the broker's side and ``robots`` in ``broker.py``."""

from __future__ import annotations

import argparse
import logging
import sys
from datetime import UTC
from pathlib import Path

from backend.cli.accounts import create_admin, users
from backend.cli.broker import broker_init, broker_user, legacy_sentinel, robots
from backend.core.config import Settings
from backend.core.logging import setup_logging

log = logging.getLogger("backend")


def _serve(settings: Settings, host: str, port: int) -> int:
    import uvicorn

    from backend.api.routes.ws import MAX_CLIENT_MESSAGE
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
        # no WebSocket handler takes a message over 64 KiB: a larger one is refused by the protocol (close
        # 1009) before it is buffered whole (uvicorn's default accepts 16 MiB per message)
        ws_max_size=MAX_CLIENT_MESSAGE,
        lifespan="on",
        # h11, not httptools: the longest query the API documents (robots: 8,000 characters, up to 12 bytes
        # each once percent-encoded) must reach its route and get a 422 there with a code, and httptools
        # answers a bare 400 to any URL over 64 KiB (its URL parser keeps 16-bit offsets)
        http="h11",
        h11_max_incomplete_event_size=128 * 1024,
        timeout_keep_alive=settings.http_keepalive_s,
    )
    uvicorn.Server(config).run()
    return 0


def _db(settings: Settings, action: str, revision: str | None = None) -> int:
    from backend.store.db import create_db_engine, current_revision, downgrade_to, upgrade_to_head

    if action == "downgrade" and not revision:
        print("fleet-server db downgrade: give the revision to go back to (e.g. 0002; base = empty)", file=sys.stderr)
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


FORCE_HELP = (
    "use the database even when FLEET_DATABASE_URL does not name it (the default ./data/fleet.db) "
    "or it holds no server schema yet (creates it)"
)


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
    ca.add_argument("--force", action="store_true", help=FORCE_HELP)
    us = sub.add_parser("users", help="dashboard users: add (or reset password/role), list, remove")
    us.add_argument("action", choices=["add", "list", "remove"])
    us.add_argument("name", nargs="?", default="")
    us.add_argument("--role", choices=["viewer", "operator", "admin"], default="viewer")
    us.add_argument("--password-stdin", action="store_true", help="read the password from stdin")
    us.add_argument("--force", action="store_true", help=FORCE_HELP)
    rb = sub.add_parser(
        "robots",
        help="add|remove: a robot's broker credentials (Mosquitto password file); forget: the server forgets it; "
        "legacy-add|legacy-remove: whether it may speak on the old framework's topics",
        description="add / remove: the robot's broker credentials in the Mosquitto password file (remove "
        "keeps it in the fleet list and keeps its data); add also stores a single-use enrolment in the server's "
        "database and prints the one line the robot's Pi runs (install-pi.sh --enrol SERVER TOKEN). forget: the "
        "running server forgets a robot that is gone (fleet list, database row, retained status on the broker; "
        "telemetry kept unless --telemetry delete) and keeps its credentials. A robot that must never come back "
        "needs both. legacy-add / legacy-remove: the running server takes (or refuses) the robot's messages on the old "
        "framework's anonymous topics (robots still on the original Mollusca framework).",
    )
    rb.add_argument("action", choices=["add", "remove", "forget", "legacy-add", "legacy-remove"])
    rb.add_argument("robot_id")
    rb.add_argument(
        "--telemetry",
        choices=["keep", "delete"],
        default="keep",
        help="forget: keep (default) or delete its stored telemetry",
    )
    rb.add_argument(
        "--listens-on",
        choices=["shared", "own"],
        default="shared",
        help="legacy-add: the command topic it listens on (the seed's code: shared)",
    )
    rb.add_argument("--server", default="http://127.0.0.1:8000", help="forget, legacy-*: the running server's URL")
    rb.add_argument(
        "--token", default=None, help="forget, legacy-*: an admin token (default FLEET_TOKEN, then FLEET_ADMIN_TOKEN)"
    )
    rb.add_argument(
        "--password-file", type=Path, default=None, help="Mosquitto password file (default FLEET_MQTT_PASSWORD_FILE)"
    )
    rb.add_argument(
        "--broker", default=None, help="add: the broker URL the robot is given (default: it discovers the broker)"
    )
    rb.add_argument(
        "--enrol-url",
        default=None,
        help="add: this server's address as the robot reaches it, for the enrolment line (default: "
        "http://<this host's LAN address>:8000)",
    )
    rb.add_argument("--enrol-ttl", type=float, default=30.0, help="add: minutes the enrolment stays usable (30)")
    rb.add_argument("--tls-ca", type=Path, default=None, help="add: CA of the broker's TLS listener, for the robot")
    rb.add_argument(
        "--print-password",
        action="store_true",
        help="add: no enrolment (no database needed): print the agent config with the password instead",
    )
    rb.add_argument("--force", action="store_true", help="add: " + FORCE_HELP)
    bu = sub.add_parser("broker-user", help="broker credentials for the server (or another client)")
    bu.add_argument("username", nargs="?", default="fleet-server")
    bu.add_argument("--password-file", type=Path, default=None)
    bu.add_argument("--broker-host", default="mosquitto:1883", help="host:port for the printed FLEET_MQTT_URL")
    bi = sub.add_parser("broker-init", help="broker password file + ACL from the environment (compose)")
    bi.add_argument("auth_dir", type=Path, help="directory Mosquitto reads passwd and acl from")
    bi.add_argument(
        "--acl-template",
        type=Path,
        default=Path(__file__).resolve().parents[1] / "deploy" / "mosquitto" / "acl.example",
        help="ACL installed when the directory has none",
    )
    bi.add_argument("--sim-robots", default="", help="comma-separated ids given FLEET_SIM_ROBOT_PASSWORD")
    sub.add_parser("legacy-sentinel", help="beside the broker: stop old-framework robots when the server goes silent")
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
        return create_admin(settings, args.name, args.force)
    if args.cmd == "users":
        if args.action != "list" and not args.name:
            print("fleet-server users: a user name is required", file=sys.stderr)
            return 2
        return users(settings, args)
    if args.cmd == "robots":
        return robots(settings, args)
    if args.cmd == "broker-user":
        return broker_user(settings, args)
    if args.cmd == "broker-init":
        return broker_init(settings, args)
    if args.cmd == "legacy-sentinel":
        return legacy_sentinel(settings)
    if args.cmd in ("backup", "restore", "export"):
        return _ops(settings, args)
    return _serve(settings, getattr(args, "host", "0.0.0.0"), getattr(args, "port", 8000))


if __name__ == "__main__":
    sys.exit(main())
