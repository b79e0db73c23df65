"""CLI commands that act through the running server (it holds the fleet's state): an admin request to its
REST API, with the token from ``--token``, ``FLEET_TOKEN`` or ``FLEET_ADMIN_TOKEN``."""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from backend.core.config import Settings


def admin_request(
    settings: Settings, args: argparse.Namespace, what: str, method: str, path: str, **kwargs: Any
) -> dict[str, Any] | None:
    """The JSON answer, or None after printing why it failed (``fleet-server WHAT: ...`` on stderr)."""
    import httpx

    token = args.token or os.environ.get("FLEET_TOKEN") or settings.admin_token.get_secret_value()
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    try:
        r = httpx.request(method, f"{args.server.rstrip('/')}{path}", headers=headers, timeout=60, **kwargs)
    except httpx.HTTPError as exc:
        print(f"fleet-server {what}: cannot reach {args.server}: {exc}", file=sys.stderr)
        return None
    if r.status_code != 200:
        try:
            body = r.json()
            why = f"{body.get('detail')} ({body.get('code')})"
        except ValueError:
            why = r.text[:300]
        print(f"fleet-server {what}: {r.status_code}: {why}", file=sys.stderr)
        return None
    answer: dict[str, Any] = r.json()
    return answer


def legacy_robot(settings: Settings, args: argparse.Namespace) -> int:
    """``robots legacy-add|legacy-remove ID``: which robots may speak on the old framework's topics."""
    what = f"robots {args.action}"
    if args.action == "legacy-add":
        done = admin_request(
            settings, args, what, "PUT", f"/api/robots/{args.robot_id}/legacy", json={"listens_on": args.listens_on}
        )
        if done is None:
            return 1
        print(
            f"robot {done['id']} registered as on the old framework (listens on the {args.listens_on} command "
            "topic): its messages on robot/sensor_data/... are taken from now on"
        )
        return 0
    done = admin_request(settings, args, what, "DELETE", f"/api/robots/{args.robot_id}/legacy")
    if done is None:
        return 1
    print(f"robot {done['id']} no longer registered as on the old framework: its old-topic messages are refused")
    return 0
