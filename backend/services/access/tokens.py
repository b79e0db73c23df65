"""API tokens (database side): made, listed, revoked and looked up.

Every token expires: ``FLEET_TOKEN_TTL_DAYS`` after it is made, or sooner when ``expires_in_s`` asks (a longer
lifetime is refused, so no token lives forever). A token made by a logged-in user, or by a token that answers
to one, answers to that user (``api_tokens.user_id``): it stops working while the user is disabled, once they
are deleted, or when they are demoted below the token's role, as the user's own sessions do. Tokens made with
``FLEET_ADMIN_TOKEN`` or the CLI answer to nobody and are bound only by their expiry.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from sqlalchemy import Engine, Select, insert, or_, select, update

from backend.core.errors import ServiceError
from backend.core.security import Principal, Role, hash_token, new_id, new_secret
from backend.models import ApiToken, User
from backend.schemas import TokenCreate, TokenCreated, TokenPublic

log = logging.getLogger("backend.auth")

DAY_S = 86400.0


def with_owner() -> Select[*tuple[Any, ...]]:
    """A token (or session) with the user it answers to: what deciding whether it is valid now needs (its
    lookup here, and the sockets' re-read of their principals once a second)."""
    return select(
        ApiToken.id,
        ApiToken.name,
        ApiToken.kind,
        ApiToken.role,
        ApiToken.revoked_at,
        ApiToken.expires_at,
        ApiToken.user_id,
        User.username,
        User.role.label("user_role"),
        User.disabled,
    ).outerjoin(User, User.id == ApiToken.user_id)


def owner_allows(user_id: int | None, username: str | None, user_role: str | None, disabled: Any, role: Role) -> bool:
    """Whether a token of ``role`` still answers to its user (``user_id`` None: it answers to nobody); the user
    columns come from an outer join, so a deleted user reads as ``username`` None."""
    if user_id is None:
        return True
    if username is None or disabled:
        return False
    try:
        return Role.parse(user_role or "") >= role
    except ValueError:
        return False


def token_public(row: Any) -> TokenPublic:
    return TokenPublic(
        id=row.id,
        name=row.name,
        role=row.role,
        created_at=row.created_at,
        created_by=row.created_by,
        expires_at=row.expires_at,
        last_used_at=row.last_used_at,
        revoked=row.revoked_at is not None,
        owner=row.owner,
    )


class _Row:
    """Attribute access to a dict, for building a TokenPublic from the values just inserted."""

    def __init__(self, values: dict[str, Any]) -> None:
        self.__dict__.update(values)


class ApiTokens:
    def __init__(self, engine: Engine, ttl_days: float) -> None:
        self._engine = engine
        self.ttl_s = ttl_days * DAY_S

    def create(self, body: TokenCreate, created_by: str, owner: str | None) -> TokenCreated:
        """A new token (its secret in the answer only). ``owner``: the user the maker answers to (None: nobody)."""
        if body.expires_in_s is not None and body.expires_in_s > self.ttl_s:
            raise ServiceError(
                422,
                f"expires_in_s: at most {self.ttl_s:.0f} s ({self.ttl_s / DAY_S:g} days, FLEET_TOKEN_TTL_DAYS)",
                "token_lifetime_too_long",
            )
        now = time.time()
        secret = new_secret()
        values: dict[str, Any] = {
            "id": new_id("tok_"),
            "kind": "api",
            "name": body.name,
            "role": body.role,
            "user_id": None,
            "token_hash": hash_token(secret),
            "created_at": now,
            "created_by": created_by[:120],
            "expires_at": now + (self.ttl_s if body.expires_in_s is None else float(body.expires_in_s)),
            "last_used_at": None,
            "revoked_at": None,
        }
        with self._engine.begin() as conn:
            if owner is not None:
                user = conn.execute(select(User.id, User.role, User.disabled).where(User.username == owner)).first()
                if user is None or not owner_allows(user.id, owner, user.role, user.disabled, Role.parse(body.role)):
                    raise ServiceError(403, f"user {owner!r} may not make a {body.role} token", "owner_not_allowed")
                values["user_id"] = user.id
            conn.execute(insert(ApiToken).values(**values))
        log.info("API token %s (%s, %s) created by %s", values["id"], body.name, body.role, created_by)
        return TokenCreated(**token_public(_Row({**values, "owner": owner})).model_dump(), token=secret)

    def list_all(self) -> list[TokenPublic]:
        with self._engine.connect() as conn:
            rows = conn.execute(
                select(ApiToken, User.username.label("owner"))
                .outerjoin(User, User.id == ApiToken.user_id)
                .where(ApiToken.kind == "api")
                .order_by(ApiToken.created_at)
            )
            return [token_public(r) for r in rows]

    def revoke(self, token_id: str) -> None:
        with self._engine.begin() as conn:
            result = conn.execute(
                update(ApiToken)
                .where(ApiToken.id == token_id, ApiToken.kind == "api", ApiToken.revoked_at.is_(None))
                .values(revoked_at=time.time())
            )
            if result.rowcount == 0:
                exists = conn.execute(
                    select(ApiToken.id).where(ApiToken.id == token_id, ApiToken.kind == "api")
                ).first()
                if exists is None:
                    raise ServiceError(404, f"unknown token {token_id!r}", "unknown_token")
        log.info("API token %s revoked", token_id)

    def find(self, *where: Any) -> Principal | None:
        """The principal of the one valid token matching ``where``: not revoked, not expired, its user (if it
        has one) present, enabled and holding at least its role."""
        with self._engine.connect() as conn:
            row = conn.execute(with_owner().where(ApiToken.kind == "api", *where)).first()
        if row is None or row.revoked_at is not None or (row.expires_at is not None and row.expires_at <= time.time()):
            return None
        try:
            role = Role.parse(row.role or "")
        except ValueError:
            return None
        if not owner_allows(row.user_id, row.username, row.user_role, row.disabled, role):
            return None
        return Principal(f"token:{row.id}", row.name, role, "token", token_id=row.id, owner=row.username)

    def cap_lifetimes(self) -> int:
        """At start: no live token lives past now + the TTL (those made before tokens expired had none, or
        the TTL was lowered since); returns how many were cut."""
        cap = time.time() + self.ttl_s
        with self._engine.begin() as conn:
            result = conn.execute(
                update(ApiToken)
                .where(
                    ApiToken.kind == "api",
                    ApiToken.revoked_at.is_(None),
                    or_(ApiToken.expires_at.is_(None), ApiToken.expires_at > cap),
                )
                .values(expires_at=cap)
            )
        if result.rowcount:
            log.warning(
                "%d API token(s) without an expiry or beyond FLEET_TOKEN_TTL_DAYS now expire in %g days",
                result.rowcount,
                self.ttl_s / DAY_S,
            )
        return int(result.rowcount)
