"""The API shapes of users, tokens and logins (apart from the service that stores them, services/access/auth.py)."""

from __future__ import annotations

from pydantic import BaseModel, Field, StrictBool

from backend.core.security import (
    MAX_PASSWORD_LENGTH,
    MIN_PASSWORD_LENGTH,
    USERNAME_PATTERN,
    RoleName,
    TokenRoleName,
)
from fleet_protocol import StrictNumber


class UserPublic(BaseModel):
    username: str
    role: RoleName
    disabled: bool
    created_at: float
    updated_at: float


class UserCreate(BaseModel):
    username: str = Field(pattern=USERNAME_PATTERN)
    password: str = Field(min_length=MIN_PASSWORD_LENGTH, max_length=MAX_PASSWORD_LENGTH)
    role: RoleName = "viewer"


class UserUpdate(BaseModel):
    password: str | None = Field(default=None, min_length=MIN_PASSWORD_LENGTH, max_length=MAX_PASSWORD_LENGTH)
    role: RoleName | None = None
    disabled: StrictBool | None = None  # JSON true/false only (0 or "no" is refused, not read as false)


class TokenPublic(BaseModel):
    id: str
    name: str
    role: TokenRoleName
    created_at: float
    created_by: str
    #: when it stops working (null only for a token made before tokens expired; docs/upgrading.md)
    expires_at: float | None
    last_used_at: float | None
    revoked: bool
    #: the user it answers to (disabled, deleted or demoted below its role: the token stops working)
    owner: str | None = None


class TokenCreate(BaseModel):
    name: str = Field(min_length=1, max_length=120)
    #: ``metrics``: ``GET /metrics`` only (a Prometheus scrape)
    role: TokenRoleName = "viewer"
    expires_in_s: StrictNumber | None = Field(
        default=None,
        gt=0,
        le=10 * 365 * 86400,
        description="lifetime in seconds; default and maximum FLEET_TOKEN_TTL_DAYS (90 days): more is refused (422)",
    )


class TokenCreated(TokenPublic):
    #: The secret itself: shown once, only its hash is stored.
    token: str


class LoginRequest(BaseModel):
    username: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=MAX_PASSWORD_LENGTH)


class Me(BaseModel):
    name: str
    role: RoleName
    kind: str
    username: str | None
    auth: bool
    #: who the caller is as a control-lease holder (with authentication off each client sends its own id)
    subject: str = ""
