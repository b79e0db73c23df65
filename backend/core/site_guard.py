"""Host and Origin checks on every request, whatever ``FLEET_AUTH`` says.

With authentication off any page the operator visits could otherwise act on the server: a form or ``fetch``
from ``http://evil.example`` (refused by the Origin check) or, after DNS rebinding, a page whose own origin
*is* the server's address under the attacker's name (``Host: evil.example``: refused by the Host check, as
rebinding needs a name and the server answers only to its own). An IP-literal Host cannot be rebound, so any
is accepted; names are ``localhost``, this machine's names and ``FLEET_ALLOWED_HOSTS``.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import socket
from collections.abc import Iterable

from starlette.types import ASGIApp, Receive, Scope, Send

from backend.core.security import origin_allowed

log = logging.getLogger("backend.security")

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


def machine_host_names() -> frozenset[str]:
    """``localhost`` and the names this machine goes by (its hostname, FQDN and mDNS ``.local`` name)."""
    names = {"localhost"}
    try:
        hostname = socket.gethostname()
        names.update({hostname, f"{hostname}.local", socket.getfqdn()})
    except OSError:  # pragma: no cover - a machine without a name still has localhost
        pass
    return frozenset(n.strip().rstrip(".").lower() for n in names if n)


def parse_allowed_hosts(value: str) -> frozenset[str]:
    """``FLEET_ALLOWED_HOSTS``: comma-separated names (``fleet.lab.example``), ``.lab.example`` for every
    name under a domain, ``*`` for any Host (the check off)."""
    return frozenset(h.strip().rstrip(".").lower() for h in value.split(",") if h.strip())


def host_name(header: str) -> str:
    """The name of a Host header, without port or IPv6 brackets, lower case."""
    header = header.strip().lower()
    if header.startswith("["):
        return header[1 : header.find("]")] if "]" in header else header
    name, _, _port = header.rpartition(":") if header.count(":") == 1 else (header, "", "")
    return name.rstrip(".")


def host_allowed(header: str | None, allowed: Iterable[str]) -> bool:
    if not header:
        return False
    name = host_name(header)
    try:
        ipaddress.ip_address(name)
        return True  # an address cannot be rebound to another: the browser's origin is that address
    except ValueError:
        pass
    return any(e == "*" or e == name or (e.startswith(".") and name.endswith(e)) for e in allowed)


class SiteGuardMiddleware:
    """400 for a Host this server does not answer to, 403 for a write or WebSocket handshake from a foreign
    Origin (requests without Origin, i.e. scripts, pass)."""

    def __init__(self, app: ASGIApp, *, allowed_hosts: frozenset[str], allowed_origins: frozenset[str]) -> None:
        self.app = app
        self.allowed_hosts = machine_host_names() | allowed_hosts
        self.allowed_origins = allowed_origins
        self.refused_hosts = 0
        self.refused_origins = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope.get("headers", [])}
        host = headers.get("host")
        if not host_allowed(host, self.allowed_hosts):
            self.refused_hosts += 1
            shown = (host or "")[:100]
            log.warning("refused a request for Host %r (not in FLEET_ALLOWED_HOSTS)", shown)
            detail = (
                f"this server does not answer to the Host {shown!r}: if that is its name, add it to "
                "FLEET_ALLOWED_HOSTS (comma-separated)"
            )
            await _refuse(
                scope, receive, send, 400, detail, "host_not_allowed", "host not allowed (FLEET_ALLOWED_HOSTS)"
            )
            return
        checks_origin = scope["type"] == "websocket" or scope.get("method", "GET") not in SAFE_METHODS
        if checks_origin and not origin_allowed(headers.get("origin"), host, self.allowed_origins):
            self.refused_origins += 1
            detail = "cross-origin request refused (allow an origin with FLEET_ALLOWED_ORIGINS)"
            await _refuse(scope, receive, send, 403, detail, "cross_origin", "origin not allowed")
            return
        await self.app(scope, receive, send)


async def _refuse(scope: Scope, receive: Receive, send: Send, status: int, detail: str, code: str, reason: str) -> None:
    if scope["type"] == "websocket":  # accepted and closed at once with a reason, as deps.py refuses sockets
        await receive()  # websocket.connect
        await send({"type": "websocket.accept"})
        await send({"type": "websocket.close", "code": 1008, "reason": reason})
        return
    body = json.dumps({"detail": detail, "code": code}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())],
        }
    )
    await send({"type": "http.response.body", "body": body})
