"""Alarms: each alarm and its transitions, and an admin's thresholds for the built-in rules."""

from __future__ import annotations

from typing import Any

from sqlalchemy import JSON, BigInteger, Boolean, Double, Index, String, Text, text
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base, BigId


class AlarmRow(Base):
    """An alarm: active -> acknowledged -> cleared. At most one not-cleared alarm per (robot, kind): the
    partial unique index makes the database the arbiter when several replicas raise the same one."""

    __tablename__ = "alarms"
    __table_args__ = (
        Index("ix_alarms_state_raised", "state", "raised_at"),
        Index(
            "uq_alarms_open",
            "robot_key",
            "kind",
            unique=True,
            sqlite_where=text("cleared_at IS NULL"),
            postgresql_where=text("cleared_at IS NULL"),
        ),
    )

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    #: the robot, or "" for a fleet-wide alarm (a unique index treats NULLs as distinct)
    robot_key: Mapped[str] = mapped_column(String(64))
    kind: Mapped[str] = mapped_column(String(48))
    severity: Mapped[str] = mapped_column(String(16))
    state: Mapped[str] = mapped_column(String(16))
    message: Mapped[str] = mapped_column(Text, default="")
    detail: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    raised_at: Mapped[float] = mapped_column(Double)
    acked_at: Mapped[float | None] = mapped_column(Double, nullable=True)
    acked_by: Mapped[str | None] = mapped_column(String(160), nullable=True)
    cleared_at: Mapped[float | None] = mapped_column(Double, nullable=True)


class AlarmTransitionRow(Base):
    """Every state change of an alarm, with who made it (``system`` for the rules themselves)."""

    __tablename__ = "alarm_transitions"
    __table_args__ = (Index("ix_alarm_transitions_alarm", "alarm_id"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    alarm_id: Mapped[int] = mapped_column(BigInteger)
    ts: Mapped[float] = mapped_column(Double)
    state: Mapped[str] = mapped_column(String(16))
    by: Mapped[str] = mapped_column(String(160))


class AlarmRuleRow(Base):
    """An admin's thresholds for a built-in rule (``PUT /api/alarm-rules``); absent rows use the settings."""

    __tablename__ = "alarm_rules"

    kind: Mapped[str] = mapped_column(String(48), primary_key=True)
    enabled: Mapped[bool] = mapped_column(Boolean, default=True)
    params: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    updated_at: Mapped[float] = mapped_column(Double)
    updated_by: Mapped[str] = mapped_column(String(160), default="")
