"""Authentication (issue 6): users and their bearer credentials (API tokens and browser sessions)."""

from __future__ import annotations

from sqlalchemy import Boolean, Double, Index, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base, BigId


class User(Base):
    """A person who logs in to the dashboard. ``role``: viewer | operator | admin."""

    __tablename__ = "users"

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    username: Mapped[str] = mapped_column(String(64), unique=True)
    password_hash: Mapped[str] = mapped_column(Text)
    role: Mapped[str] = mapped_column(String(16))
    disabled: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[float] = mapped_column(Double)
    updated_at: Mapped[float] = mapped_column(Double)


class ApiToken(Base):
    """Bearer credentials, stored as sha256 (API tokens) or HMAC (browser sessions) of the secret.

    ``kind`` "api": a script's token with its own ``role``. ``kind`` "session": a logged-in browser; its
    role is the user's current role (``user_id``), so a role change or a disabled user applies at once.
    """

    __tablename__ = "api_tokens"
    __table_args__ = (Index("ix_api_tokens_kind", "kind"),)

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    kind: Mapped[str] = mapped_column(String(16))
    name: Mapped[str] = mapped_column(String(120))
    role: Mapped[str | None] = mapped_column(String(16), nullable=True)
    user_id: Mapped[int | None] = mapped_column(BigId, nullable=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[float] = mapped_column(Double)
    created_by: Mapped[str] = mapped_column(String(120), default="")
    expires_at: Mapped[float | None] = mapped_column(Double, nullable=True)
    last_used_at: Mapped[float | None] = mapped_column(Double, nullable=True)
    revoked_at: Mapped[float | None] = mapped_column(Double, nullable=True)
