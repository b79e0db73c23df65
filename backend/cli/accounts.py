"""``fleet-server create-admin`` and ``users add|list|remove``: accounts in the server's database."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from backend.core.config import Settings

if TYPE_CHECKING:
    from sqlalchemy import Engine

    from backend.services.access.auth import AuthService


def _auth_service(settings: Settings, force: bool) -> tuple[AuthService, Engine]:
    """The auth service on the server's database; TargetDatabaseError when it is probably not the server's
    (see backend/store/target.py), before anything is created or written."""
    from backend.services.access.auth import AuthService
    from backend.store.db import create_db_engine, upgrade_to_head
    from backend.store.target import check_named, check_schema

    check_named(settings, force=force)
    engine = create_db_engine(settings)
    try:
        check_schema(settings, engine, force=force)
        upgrade_to_head(engine)
    except BaseException:
        engine.dispose()
        raise
    return AuthService(settings, engine), engine


def _audit(engine: Engine, action: str, detail: dict[str, object]) -> None:
    """The audit trail records what the CLI changed too, as done by the operating-system account that ran it."""
    import getpass
    import time

    from backend.store.audit import insert_audit

    try:
        who = getpass.getuser()
    except (KeyError, OSError):
        who = "unknown"
    values = {
        "ts": time.time(),
        "actor": f"cli:{who}"[:160],
        "actor_name": f"{who} (fleet-server CLI)"[:160],
        "token_id": None,
        "client": "cli",
        "action": action,
        "robot_id": None,
        "detail": detail,
    }
    with engine.begin() as conn:
        insert_audit(values)(conn)


def create_admin(settings: Settings, name: str, force: bool) -> int:
    from backend.schemas import TokenCreate
    from backend.store.target import TargetDatabaseError, describe_database

    try:
        auth, engine = _auth_service(settings, force)
    except TargetDatabaseError as exc:
        print(f"fleet-server create-admin: {exc}", file=sys.stderr)
        return 1
    try:
        # answers to no user; it expires as every token does (FLEET_TOKEN_TTL_DAYS)
        created = auth.tokens.create(TokenCreate(name=name, role="admin"), "fleet-server create-admin", None)
        detail: dict[str, object] = {
            "token": created.id,
            "name": name,
            "role": "admin",
            "expires_at": created.expires_at,
        }
        _audit(engine, "token_create", detail)
    finally:
        engine.dispose()
    print(f"database: {describe_database(settings)}", file=sys.stderr)
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


def users(settings: Settings, args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from backend.services.access.auth import AuthError
    from backend.store.target import TargetDatabaseError, describe_database

    try:
        auth, engine = _auth_service(settings, args.force)
    except TargetDatabaseError as exc:
        print(f"fleet-server users: {exc}", file=sys.stderr)
        return 1
    try:
        password = _read_password(args) if args.action == "add" else ""
    except ValueError as exc:
        engine.dispose()
        print(f"fleet-server users: {exc}", file=sys.stderr)
        return 1
    where = describe_database(settings)
    try:
        if args.action == "add":
            existed = any(u.username == args.name for u in auth.list_users())
            user = auth.set_user(args.name, password, args.role)
            if existed:
                _audit(engine, "user_update", {"user": user.username, "role": user.role, "password_reset": True})
            else:
                _audit(engine, "user_create", {"user": user.username, "role": user.role})
            print(f"user {user.username}: role {user.role}, written to {where}")
        elif args.action == "remove":
            auth.delete_user(args.name)
            _audit(engine, "user_delete", {"user": args.name})
            print(f"user {args.name} removed from {where}")
        else:
            print(f"# {where}", file=sys.stderr)
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
