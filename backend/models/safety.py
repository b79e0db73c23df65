"""The control lease, the audit trail, and the latest state of the e-stop and of each robot's hold."""

from __future__ import annotations

from typing import Any

from sqlalchemy import JSON, Boolean, Double, Index, String
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


class SafetyLatchRow(Base):
    """The newest state of the fleet e-stop (``kind`` "estop", ``robot_id`` "") or of one robot's hold
    (``kind`` "hold"), engaged or released, as it was on the broker. A server restores it at start and puts a
    latch back on a broker that lost it (services/safety/latches.py): the retained message alone lived only
    as long as the broker's memory."""

    __tablename__ = "safety_latches"

    kind: Mapped[str] = mapped_column(String(16), primary_key=True)
    robot_id: Mapped[str] = mapped_column(String(64), primary_key=True, default="")
    engaged: Mapped[bool] = mapped_column(Boolean)
    #: the message's own ``ts`` and ``id``: they order two states (the newer wins), not when it was stored
    ts: Mapped[float] = mapped_column(Double)
    latch_id: Mapped[str | None] = mapped_column(String(64), nullable=True)
    reason: Mapped[str] = mapped_column(String(500), default="")
    source: Mapped[str] = mapped_column(String(120), default="")
    stored_at: Mapped[float] = mapped_column(Double)
