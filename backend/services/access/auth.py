"""Users, API tokens (made, listed and looked up in tokens.py) and browser sessions (database side), and who a
bearer secret belongs to.

Every method that touches the database is synchronous (routes call them through ``run_in_threadpool``, the
CLI directly) but :meth:`AuthService.login`, whose scrypt runs on the password pool (core/workpool.py).
Successful lookups are cached for ``CACHE_TTL_S``; any change made through this service (revoke, logout,
user change) clears the cache at once. Another replica sees a revocation within ``CACHE_TTL_S``.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import logging
import threading
import time
from typing import Any

from sqlalchemy import Engine, delete, insert, select, update
from sqlalchemy.exc import IntegrityError

from backend.core.config import Settings
from backend.core.errors import ServiceError
from backend.core.security import (
    AUTH_OFF_PRINCIPAL,
    Principal,
    Role,
    RoleName,
    TokenBuckets,
    hash_password,
    hash_session,
    hash_token,
    new_id,
    new_secret,
    verify_password,
)
from backend.core.workpool import WorkPool
from backend.models import ApiToken, User
from backend.schemas import UserCreate, UserPublic, UserUpdate
from backend.services.access.login_limits import LoginLimits
from backend.services.access.tokens import ApiTokens

log = logging.getLogger("backend.auth")

CACHE_TTL_S = 5.0
#: last_used_at is written at most this often per token (not on every request).
TOUCH_INTERVAL_S = 60.0
AUTH_OFF_WARNING_INTERVAL_S = 60.0
DEV_SESSION_KEY = b"mollusca-fleet-development-session-key"


def server_key(settings: Settings) -> bytes:
    """FLEET_SECRET_KEY (every replica's), or a fixed development key without one: it signs the session ids
    and the e-stops a server publishes (services/safety/estop_audit.py)."""
    key = settings.secret_key.get_secret_value()
    return key.encode() if key else DEV_SESSION_KEY


class AuthError(ServiceError):
    """A refused login, or a user or token that does not exist (or already does)."""


def _user_public(row: Any) -> UserPublic:
    return UserPublic(
        username=row.username,
        role=row.role,
        disabled=row.disabled,
        created_at=row.created_at,
        updated_at=row.updated_at,
    )


class AuthService:
    def __init__(self, settings: Settings, engine: Engine, *, passwords: WorkPool | None = None) -> None:
        self.passwords = passwords or WorkPool("passwords", workers=1, queue_max=8)
        self.enabled = settings.auth
        self.settings = settings
        self.allowed_origins = settings.allowed_origin_set
        self.session_ttl_s = settings.session_ttl_s
        self._engine = engine
        admin = settings.admin_token.get_secret_value()
        self._env_admin_hash = hash_token(admin) if admin else None
        self._session_key = server_key(settings)
        self._lock = threading.Lock()
        self._cache: dict[tuple[str, str], tuple[Principal, float]] = {}
        self._touched: dict[str, float] = {}
        self.commands = TokenBuckets(settings.command_rate_per_s, settings.command_burst)
        self.logins = LoginLimits(settings)  # checked before any password is
        #: API tokens (``tokens.create``, ``tokens.list_all``; revoke through :meth:`revoke_token`)
        self.tokens = ApiTokens(engine, settings.token_ttl_days)
        self._warner: asyncio.Task[None] | None = None

    # -- lifecycle (event loop) ----------------------------------------------------------------------------
    def start(self) -> None:
        if not self.enabled:
            self._warn_auth_off()
            self._warner = asyncio.get_running_loop().create_task(self._keep_warning(), name="auth-off-warning")
            return
        self.tokens.cap_lifetimes()
        if self._env_admin_hash is None and not self.has_admins():
            log.warning(
                "authentication is on but there is no admin: set FLEET_ADMIN_TOKEN or run "
                "`fleet-server create-admin` (docs/security.md)"
            )

    async def stop(self) -> None:
        if self._warner is not None:
            self._warner.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._warner

    @staticmethod
    def _warn_auth_off() -> None:
        log.warning(
            "AUTHENTICATION IS OFF (FLEET_AUTH=off): anyone who can reach this server can drive the robots "
            "and change everything. Demo only; never on a network with people you do not trust."
        )

    async def _keep_warning(self) -> None:
        while True:
            await asyncio.sleep(AUTH_OFF_WARNING_INTERVAL_S)
            self._warn_auth_off()

    # -- who is calling (threadpool) ---------------------------------------------------------------------
    def _cached(self, key: tuple[str, str]) -> Principal | None:
        with self._lock:
            hit = self._cache.get(key)
            if hit is None:
                return None
            if hit[1] < time.monotonic():
                del self._cache[key]
                return None
            return hit[0]

    def _remember(self, key: tuple[str, str], principal: Principal) -> None:
        with self._lock:
            if len(self._cache) > 10_000:
                self._cache.clear()
            self._cache[key] = (principal, time.monotonic() + CACHE_TTL_S)

    def invalidate(self) -> None:
        with self._lock:
            self._cache.clear()

    def _touch(self, token_id: str, now: float) -> None:
        with self._lock:
            if now - self._touched.get(token_id, 0.0) < TOUCH_INTERVAL_S:
                return
            self._touched[token_id] = now
        try:
            with self._engine.begin() as conn:
                conn.execute(update(ApiToken).where(ApiToken.id == token_id).values(last_used_at=now))
        except Exception as exc:  # never fail a request because of bookkeeping
            log.debug("could not record last use of %s: %r", token_id, exc)

    def principal_for_token(self, token: str, memory_only: bool = False) -> Principal | None:
        """An API token or FLEET_ADMIN_TOKEN -> its principal; None when unknown, revoked or expired.
        ``memory_only``: answer only from what needs no database (the admin token, the cache), so the
        event loop can ask without a thread hop; None then may also mean "ask again without it"."""
        if not self.enabled:
            return AUTH_OFF_PRINCIPAL
        if not token or len(token) > 512:
            return None
        digest = hash_token(token)
        if self._env_admin_hash is not None and _equal(digest, self._env_admin_hash):
            return Principal("env:admin", "FLEET_ADMIN_TOKEN", Role.ADMIN, "env-token")
        key = ("t", digest)
        cached = self._cached(key)
        if cached is not None or memory_only:
            return cached
        principal = self.tokens.find(ApiToken.token_hash == digest)
        if principal is None or principal.token_id is None:
            return None
        self._remember(key, principal)
        self._touch(principal.token_id, time.time())
        return principal

    def principal_for_session(self, session_id: str, memory_only: bool = False) -> Principal | None:
        """A session cookie -> its user's principal; None when unknown, revoked, expired or the user is
        disabled (``memory_only`` as for :meth:`principal_for_token`)."""
        if not self.enabled:
            return AUTH_OFF_PRINCIPAL
        if not session_id or len(session_id) > 512:
            return None
        digest = hash_session(session_id, self._session_key)
        key = ("s", digest)
        cached = self._cached(key)
        if cached is not None or memory_only:
            return cached
        now = time.time()
        with self._engine.connect() as conn:
            row = conn.execute(
                select(ApiToken.id, ApiToken.revoked_at, ApiToken.expires_at, User.username, User.role, User.disabled)
                .join(User, User.id == ApiToken.user_id)
                .where(ApiToken.token_hash == digest, ApiToken.kind == "session")
            ).first()
        if row is None or row.revoked_at is not None or row.disabled:
            return None
        if row.expires_at is not None and row.expires_at <= now:
            return None
        try:
            role = Role.parse(row.role)
        except ValueError:
            return None
        principal = Principal(
            f"user:{row.username}", row.username, role, "session", row.id, row.username, owner=row.username
        )
        self._remember(key, principal)
        return principal

    # -- sessions ------------------------------------------------------------------------------------------
    async def login(self, username: str, password: str) -> tuple[Principal, str]:
        """-> (principal, session secret for the cookie); AuthError 401 for any wrong name or password."""
        user = await asyncio.to_thread(self._user_row, username)
        ok = await self.passwords.run(verify_password, password, user.password_hash if user is not None else None)
        if user is None or not ok or user.disabled:
            raise AuthError(401, "wrong username or password", "bad_credentials")
        return await asyncio.to_thread(self._open_session, user, username)

    async def hash_password(self, password: str) -> str:
        """scrypt (CPU, 16 MiB) on the password pool, not the loop or the database's threads: for ``create_user``
        and ``update_user`` (``password_hash``; None: they hash it themselves, as for the CLI)."""
        return await self.passwords.run(hash_password, password)

    def _user_row(self, username: str) -> Any:
        with self._engine.connect() as conn:
            return conn.execute(select(User).where(User.username == username)).first()

    def _open_session(self, user: Any, username: str) -> tuple[Principal, str]:
        now, secret, sid = time.time(), new_secret("fls_"), new_id("ses_")
        with self._engine.begin() as conn:
            # expired sessions of anyone are forgotten here, so the table does not grow forever
            conn.execute(delete(ApiToken).where(ApiToken.kind == "session", ApiToken.expires_at < now))
            conn.execute(
                insert(ApiToken).values(
                    id=sid,
                    kind="session",
                    name=f"session of {username}",
                    role=None,
                    user_id=user.id,
                    token_hash=hash_session(secret, self._session_key),
                    created_at=now,
                    created_by=username,
                    expires_at=now + self.session_ttl_s,
                )
            )
        log.info("user %s logged in", username, extra={"client": username})
        role = Role.parse(user.role)
        return Principal(f"user:{username}", username, role, "session", sid, username, owner=username), secret

    def logout(self, session_id: str) -> None:
        digest = hash_session(session_id, self._session_key)
        with self._engine.begin() as conn:
            conn.execute(delete(ApiToken).where(ApiToken.token_hash == digest, ApiToken.kind == "session"))
        self.invalidate()

    # -- users ---------------------------------------------------------------------------------------------
    def has_admins(self) -> bool:
        with self._engine.connect() as conn:
            user = conn.execute(select(User.id).where(User.role == "admin", User.disabled.is_(False))).first()
            token = conn.execute(
                select(ApiToken.id).where(
                    ApiToken.kind == "api", ApiToken.role == "admin", ApiToken.revoked_at.is_(None)
                )
            ).first()
        return user is not None or token is not None

    def list_users(self) -> list[UserPublic]:
        with self._engine.connect() as conn:
            return [_user_public(r) for r in conn.execute(select(User).order_by(User.username))]

    def create_user(self, body: UserCreate, password_hash: str | None = None) -> UserPublic:
        now = time.time()
        try:
            with self._engine.begin() as conn:
                conn.execute(
                    insert(User).values(
                        username=body.username,
                        password_hash=password_hash or hash_password(body.password),
                        role=body.role,
                        disabled=False,
                        created_at=now,
                        updated_at=now,
                    )
                )
        except IntegrityError:
            raise AuthError(409, f"user {body.username!r} exists", "user_exists") from None
        return self.get_user(body.username)

    def get_user(self, username: str) -> UserPublic:
        with self._engine.connect() as conn:
            row = conn.execute(select(User).where(User.username == username)).first()
        if row is None:
            raise AuthError(404, f"unknown user {username!r}", "unknown_user")
        return _user_public(row)

    def update_user(self, username: str, body: UserUpdate, password_hash: str | None = None) -> UserPublic:
        values: dict[str, Any] = {"updated_at": time.time()}
        if body.password is not None:
            values["password_hash"] = password_hash or hash_password(body.password)
        if body.role is not None:
            values["role"] = body.role
        if body.disabled is not None:
            values["disabled"] = body.disabled
        with self._engine.begin() as conn:
            result = conn.execute(update(User).where(User.username == username).values(**values))
            if result.rowcount == 0:
                raise AuthError(404, f"unknown user {username!r}", "unknown_user")
            if body.password is not None or body.disabled:
                user_id = conn.execute(select(User.id).where(User.username == username)).scalar_one()
                conn.execute(delete(ApiToken).where(ApiToken.kind == "session", ApiToken.user_id == user_id))
        self.invalidate()
        return self.get_user(username)

    def set_user(self, username: str, password: str, role: RoleName) -> UserPublic:
        """Create, or reset the password and role of, a user (``fleet-server users add``)."""
        try:
            return self.create_user(UserCreate(username=username, password=password, role=role))
        except AuthError as exc:
            if exc.status_code != 409:
                raise
        return self.update_user(username, UserUpdate(password=password, role=role, disabled=False))

    def delete_user(self, username: str) -> None:
        with self._engine.begin() as conn:
            user_id = conn.execute(select(User.id).where(User.username == username)).scalar_one_or_none()
            if user_id is None:
                raise AuthError(404, f"unknown user {username!r}", "unknown_user")
            conn.execute(delete(ApiToken).where(ApiToken.kind == "session", ApiToken.user_id == user_id))
            # the API tokens that answered to them are revoked: a user made later may get the same id
            conn.execute(
                update(ApiToken)
                .where(ApiToken.kind == "api", ApiToken.user_id == user_id, ApiToken.revoked_at.is_(None))
                .values(revoked_at=time.time())
            )
            conn.execute(delete(User).where(User.id == user_id))
        self.invalidate()

    # -- API tokens ----------------------------------------------------------------------------------------
    def revoke_token(self, token_id: str) -> None:
        self.tokens.revoke(token_id)
        self.invalidate()

    # -- lease holders ---------------------------------------------------------------------------------------
    def lease_holder(self, holder: str) -> tuple[str, Role] | None:
        """Who a control-lease holder id (``user:NAME``, ``token:ID``, ``env:admin``; with authentication off
        ``client:TAB``) is as this server knows them, never as a client names them: (name, role) while they may
        act; None for anyone else (unknown, revoked, expired, disabled, a mission)."""
        kind, _, key = holder.partition(":")
        if not self.enabled:
            off = AUTH_OFF_PRINCIPAL  # every caller; a browser tab or script is a holder of its own (get_actor)
            if holder == off.subject:
                return off.name, off.role
            return (f"{off.name} {holder}", off.role) if kind == "client" and key else None
        if holder == "env:admin" and self._env_admin_hash is not None:
            return "FLEET_ADMIN_TOKEN", Role.ADMIN
        if kind == "user":
            user = self._user_row(key)
            return None if user is None or user.disabled else (key, Role.parse(user.role))
        principal = self.tokens.find(ApiToken.id == key) if kind == "token" else None
        return None if principal is None else (principal.name, principal.role)


def _equal(a: str, b: str) -> bool:
    return hmac.compare_digest(a.encode(), b.encode())
