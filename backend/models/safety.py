"""The control lease and the audit trail."""

from __future__ import annotations

from typing import Any

from sqlalchemy import JSON, Double, Index, String
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base, BigId


class LeaseRow(Base):
    """Who may drive a robot now. The database is the arbiter between replicas (conditional upsert)."""

    __tablename__ = "leases"

    robot_id: Mapped[str] = mapped_column(String(64), primary_key=True)
    holder: Mapped[str] = mapped_column(String(160))
    holder_name: Mapped[str] = mapped_column(String(160))
    acquired_at: Mapped[float] = mapped_column(Double)
    last_drive: Mapped[float] = mapped_column(Double)
    via: Mapped[str] = mapped_column(String(64), default="")


class AuditRow(Base):
    """Append-only: who did what, from where, with which token. Kept apart from telemetry retention."""

    __tablename__ = "audit"
    __table_args__ = (Index("ix_audit_ts", "ts"), Index("ix_audit_action_ts", "action", "ts"))

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    ts: Mapped[float] = mapped_column(Double)
    actor: Mapped[str] = mapped_column(String(160))
    actor_name: Mapped[str] = mapped_column(String(160))
    token_id: Mapped[str | None] = mapped_column(String(32), nullable=True)
    client: Mapped[str] = mapped_column(String(120), default="")
    action: Mapped[str] = mapped_column(String(64))
    robot_id: Mapped[str | None] = mapped_column(String(64), nullable=True)
    detail: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
