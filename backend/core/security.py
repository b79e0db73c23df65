"""Security primitives: roles, principals, password and token hashing, the command rate limiter, the
request body size limit, the Origin check and token redaction in logs.

No I/O here except the ASGI middleware; the database side lives in ``backend/services/access/auth.py`` and the
FastAPI dependencies in ``backend/api/deps.py``.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import logging
import math
import re
import secrets
import threading
import time
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Literal
from urllib.parse import parse_qsl, urlsplit

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger("backend.security")


class Role(IntEnum):
    """Ordered: a higher role may do everything a lower one may. ``METRICS`` is for API tokens only (a
    Prometheus scrape): it may read ``GET /metrics`` and nothing else; users are viewer, operator or admin."""

    METRICS = 0
    VIEWER = 1
    OPERATOR = 2
    ADMIN = 3

    @classmethod
    def parse(cls, name: str) -> Role:
        try:
            return cls[name.upper()]
        except KeyError:
            raise ValueError(f"unknown role {name!r} (metrics, viewer, operator, admin)") from None

    @property
    def label(self) -> str:
        return self.name.lower()


RoleName = Literal["viewer", "operator", "admin"]
#: an API token's role: a user's, or ``metrics`` (``GET /metrics`` only)
TokenRoleName = Literal["metrics", "viewer", "operator", "admin"]
USERNAME_PATTERN = r"^[A-Za-z0-9_.@-]{1,64}$"
MIN_PASSWORD_LENGTH = 8
MAX_PASSWORD_LENGTH = 1024


PrincipalKind = Literal["token", "session", "env-token", "auth-off"]


@dataclass(frozen=True, slots=True)
class Principal:
    """Who is calling. ``subject`` identifies the caller for rate limits and audit (``user:NAME``,
    ``token:ID``); ``name`` is for people."""

    subject: str
    name: str
    role: Role
    kind: PrincipalKind
    token_id: str | None = None
    username: str | None = None
    #: the user this credential answers to: a session's user, or the user who made an API token (it stops
    #: working when that user is disabled, deleted or demoted below its role); None: nobody's (the
    #: environment's admin token, a token made by it or by the CLI, authentication off)
    owner: str | None = None

    def allows(self, role: Role) -> bool:
        return self.role >= role


AUTH_OFF_PRINCIPAL = Principal("auth-off", "anonymous (FLEET_AUTH=off)", Role.ADMIN, "auth-off")

# ---------------------------------------------------------------------------------------------------
# Secrets: tokens (sha256 of 256 random bits) and passwords (scrypt)
# ---------------------------------------------------------------------------------------------------

TOKEN_PREFIX = "flt_"
SESSION_COOKIE = "fleet_session"


def new_secret(prefix: str = TOKEN_PREFIX) -> str:
    """A bearer secret with 256 bits of entropy."""
    return prefix + secrets.token_urlsafe(32)


def new_id(prefix: str) -> str:
    """A public identifier (shown in lists, used to revoke); not a secret."""
    return prefix + secrets.token_hex(6)


def hash_token(token: str) -> str:
    """Tokens are high-entropy random strings: one sha256 is enough (no salt, no stretching needed)."""
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()


def hash_session(session_id: str, key: bytes) -> str:
    """Session ids are hashed with the server's secret key (HMAC): a leaked database alone yields no
    usable session, and changing ``FLEET_SECRET_KEY`` logs every browser out."""
    return hmac.new(key, session_id.encode("utf-8", "surrogatepass"), hashlib.sha256).hexdigest()


_SCRYPT_N, _SCRYPT_R, _SCRYPT_P = 2**14, 8, 1


def _b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).decode().rstrip("=")


def _unb64(text: str) -> bytes:
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))


def hash_password(password: str) -> str:
    """``scrypt$N$r$p$salt$hash`` (hashlib.scrypt, 16 MiB, ~50 ms)."""
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(
        password.encode("utf-8", "surrogatepass"), salt=salt, n=_SCRYPT_N, r=_SCRYPT_R, p=_SCRYPT_P, dklen=32
    )
    return f"scrypt${_SCRYPT_N}${_SCRYPT_R}${_SCRYPT_P}${_b64(salt)}${_b64(digest)}"


#: Verified against when the user does not exist, so a login takes as long for unknown names.
_DUMMY_HASH = hash_password(secrets.token_urlsafe(16))


def verify_password(password: str, stored: str | None) -> bool:
    if stored is None:
        verify_password(password, _DUMMY_HASH)
        return False
    try:
        scheme, n, r, p, salt, digest = stored.split("$")
        if scheme != "scrypt":
            return False
        expected = _unb64(digest)
        got = hashlib.scrypt(
            password.encode("utf-8", "surrogatepass"),
            salt=_unb64(salt),
            n=int(n),
            r=int(r),
            p=int(p),
            dklen=len(expected),
            maxmem=64 * 1024 * 1024,
        )
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, expected)


# ---------------------------------------------------------------------------------------------------
# Rate limiting (token buckets)
# ---------------------------------------------------------------------------------------------------


class TokenBuckets:
    """One token bucket per key: ``rate`` tokens per second, at most ``burst``. Thread-safe.

    ``take(key)`` returns 0.0 when allowed, else the seconds until a token is available.
    """

    def __init__(self, rate_per_s: float, burst: int, max_keys: int = 10_000) -> None:
        if rate_per_s <= 0 or burst < 1:
            raise ValueError("rate must be > 0 and burst >= 1")
        self.rate = rate_per_s
        self.burst = float(burst)
        self._max_keys = max_keys
        self._buckets: dict[Any, tuple[float, float]] = {}  # key -> (tokens, at)
        self._lock = threading.Lock()
        self.refused = 0

    def take(self, key: Any, now: float | None = None) -> float:
        now = time.monotonic() if now is None else now
        with self._lock:
            tokens, at = self._buckets.get(key, (self.burst, now))
            tokens = min(self.burst, tokens + (now - at) * self.rate)
            if tokens >= 1.0:
                self._buckets[key] = (tokens - 1.0, now)
                if len(self._buckets) > self._max_keys:
                    self._prune(now)
                return 0.0
            self._buckets[key] = (tokens, now)
            self.refused += 1
            return (1.0 - tokens) / self.rate

    def _prune(self, now: float) -> None:
        """Forget full buckets (they behave exactly like unknown keys)."""
        full_after = self.burst / self.rate
        for key in [k for k, (_, at) in self._buckets.items() if now - at >= full_after]:
            del self._buckets[key]

    def retry_after_header(self, wait_s: float) -> str:
        return str(max(1, math.ceil(wait_s)))


# ---------------------------------------------------------------------------------------------------
# Origin checks (WebSocket handshakes and cookie-authenticated writes)
# ---------------------------------------------------------------------------------------------------


def origin_allowed(origin: str | None, host: str | None, allowed: frozenset[str]) -> bool:
    """No Origin header (scripts, curl): allowed. A browser's Origin must be this server's own host
    (scheme ignored: TLS may end at a proxy) or one of the configured ``FLEET_ALLOWED_ORIGINS``."""
    if origin is None:
        return True
    origin = origin.strip().rstrip("/").lower()
    if origin in allowed or "*" in allowed:
        return True
    if origin == "null" or not host:
        return False
    parts = urlsplit(origin)
    return parts.scheme in ("http", "https") and parts.netloc == host.strip().lower()


# ---------------------------------------------------------------------------------------------------
# Request body size limit (413)
# ---------------------------------------------------------------------------------------------------


class _BodyTooLarge(HTTPException):
    """An HTTPException so FastAPI re-raises it from body parsing instead of turning it into a 400."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than {limit} bytes")


class BodySizeLimitMiddleware:
    """Refuses request bodies over ``max_bytes`` with 413: at once from Content-Length, or while
    streaming a chunked body (the app never sees more than the limit)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    length = int(value)
                except ValueError:
                    length = -1
                if length < 0:
                    await _send_json(send, 400, b'{"detail":"bad Content-Length","code":"bad_request"}')
                    return
                if length > self.max_bytes:
                    body = b'{"detail":"request body too large (%d bytes max)","code":"payload_too_large"}'
                    await _send_json(send, 413, body % self.max_bytes)
                    return
        received = 0

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise _BodyTooLarge(self.max_bytes)
            return message

        await self.app(scope, limited_receive, send)


async def _send_json(send: Send, status: int, body: bytes) -> None:
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


class RepeatedQueryMiddleware:
    """Refuses ``/api/`` requests that repeat a query parameter (``?robot_id=a&robot_id=b``) with 422.

    FastAPI silently keeps the last value of a repeated scalar parameter; a proxy or log may read the
    first, so the request means different things to different readers (HTTP parameter pollution). No API
    route takes a repeated parameter; add its name to ``allow`` if one ever does.
    """

    def __init__(self, app: ASGIApp, allow: frozenset[str] = frozenset()) -> None:
        self.app = app
        self.allow = allow

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope.get("path", "").startswith("/api/") and scope.get("query_string"):
            seen: set[str] = set()
            for key, _ in parse_qsl(scope["query_string"].decode("latin-1"), keep_blank_values=True):
                if key in seen and key not in self.allow:
                    detail = f"query parameter {key[:64]!r} given more than once"
                    body = json.dumps({"detail": detail, "code": "repeated_query"}).encode()
                    await _send_json(send, 422, body)
                    return
                seen.add(key)
        await self.app(scope, receive, send)


# ---------------------------------------------------------------------------------------------------
# Logs never carry secrets (``?token=`` on WebSocket URLs)
# ---------------------------------------------------------------------------------------------------

_TOKEN_IN_URL = re.compile(r"((?:^|[?&])(?:token|access_token)=)[^&\s\"']+", re.IGNORECASE)


def redact(text: str) -> str:
    return _TOKEN_IN_URL.sub(r"\1***", text)


class RedactTokens(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:
            return True
        if "token=" in message.lower():
            record.msg, record.args = redact(message), ()
        return True


def install_log_redaction() -> None:
    """uvicorn logs request paths with their query (``"WebSocket /ws?token=..." [accepted]``)."""
    for name in ("uvicorn.error", "uvicorn.access", "uvicorn"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactTokens) for f in logger.filters):
            logger.addFilter(RedactTokens())
