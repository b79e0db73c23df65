"""What `make demo` prints, and the first admin it creates when authentication is on.

With FLEET_AUTH=on the demo used to print only an admin token and point to /docs to make a user; now it
creates (or resets) the dashboard user ``admin`` with a fresh random password, printed once, so the login
page works at once. The password is new on every start (an old one from earlier demo state stops working).
"""

from __future__ import annotations

import json
import secrets
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path

ADMIN_USER = "admin"


@dataclass(frozen=True)
class Login:
    username: str
    password: str


def _send(method: str, url: str, token: str, body: dict[str, object]) -> int:
    req = urllib.request.Request(
        url,
        data=json.dumps(body).encode(),
        method=method,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "application/json"},
    )
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return int(r.status)
    except urllib.error.HTTPError as exc:
        return int(exc.code)


def first_admin(base_url: str, token: str) -> Login:
    """The dashboard admin: created with a new password, or (left from earlier demo state) reset to it."""
    password = secrets.token_urlsafe(12)
    status = _send(
        "POST", f"{base_url}/api/users", token, {"username": ADMIN_USER, "password": password, "role": "admin"}
    )
    if status == 409:
        status = _send(
            "PATCH",
            f"{base_url}/api/users/{ADMIN_USER}",
            token,
            {"password": password, "role": "admin", "disabled": False},
        )
    if status not in (200, 201):
        raise RuntimeError(f"could not create the demo admin user (HTTP {status})")
    return Login(ADMIN_USER, password)


def summary(
    port: int,
    broker_url: str,
    broker_kind: str,
    ids: list[str],
    token: str | None,
    browser_hint: bool,
    admin: Login | None,
    lan: str | None,
    logs: Path | None = None,
) -> str:
    broker_port = broker_url.rsplit(":", 1)[1]
    curl_auth = f' -H "Authorization: Bearer {token}"' if token else ""
    lines = [
        "",
        "Mollusca Fleet demo is running",
        f"  dashboard   http://localhost:{port}/        (API docs: http://localhost:{port}/docs)",
        f"  broker      {broker_url}  [{broker_kind}]",
    ]
    if lan:
        lines.append(f"  on the LAN  dashboard http://{lan}:{port}/   robots: --broker mqtt://{lan}:{broker_port}")
    else:
        lines.append("  listening   on 127.0.0.1 only (this machine); --lan opens the server and broker to the LAN")
    lines += [
        f"  robots      {', '.join(ids)} (simulated)",
        f"  auth        {f'on; admin token {token}' if token else 'off (demo; FLEET_AUTH=on turns it on)'}",
    ]
    if admin:
        lines.append(
            f"  log in as   {admin.username} / {admin.password}   (one-time: a new password on every "
            "start; add users and tokens on the Users page)"
        )
    if logs:
        lines.append(f"  logs        {logs}")
    if ids:
        lines.append(
            f"  drive one:  curl -X POST{curl_auth} -H 'Content-Type: application/json' "
            f'-d \'{{"command": "move_forward", "args": {{"speed": 0.5, "duration_s": 1}}}}\' '
            f"'http://localhost:{port}/api/robots/{ids[0]}/commands?wait=3'"
        )
    if browser_hint:
        lines.append(
            f"Open http://localhost:{port}/ in a browser: hold a drive button or use the arrow keys; "
            "Esc is the fleet e-stop."
        )
    lines.append("Ready. Ctrl-C stops everything.")
    return "\n".join(lines)
