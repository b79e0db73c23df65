"""Pending and used robot enrolments (issue 29 #3; backend/core/enrolment.py says how a token is kept)."""

from __future__ import annotations

from sqlalchemy import Double, Index, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base


class EnrolmentRow(Base):
    """One single-use enrolment token of one robot. Used, expired and replaced rows stay (without the
    sealed password) so that a second try gets "used", not "unknown"."""

    __tablename__ = "enrolments"
    __table_args__ = (Index("ix_enrolments_robot_id", "robot_id"),)

    token_hash: Mapped[str] = mapped_column(String(64), primary_key=True)
    robot_id: Mapped[str] = mapped_column(String(64))
    #: the robot's broker password sealed with the token (hex); "" once used or replaced
    password_sealed: Mapped[str] = mapped_column(String(600), default="")
    #: the broker URL the robot is told (None: it discovers the broker, pinned by the fleet key)
    broker: Mapped[str | None] = mapped_column(String(500), nullable=True)
    #: the CA certificate (PEM) of the broker's TLS listener, handed to the robot as its pin
    tls_ca: Mapped[str | None] = mapped_column(Text, nullable=True)
    created_at: Mapped[float] = mapped_column(Double)
    created_by: Mapped[str] = mapped_column(String(160), default="")
    expires_at: Mapped[float] = mapped_column(Double)
    #: when it was used, and by which address ("replaced": a newer enrolment of the robot voided it)
    used_at: Mapped[float | None] = mapped_column(Double, nullable=True)
    used_by: Mapped[str | None] = mapped_column(String(120), nullable=True)
