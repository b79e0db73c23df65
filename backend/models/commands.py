"""Commands sent to robots and the acknowledgements they sent back."""

from __future__ import annotations

from typing import Any

from sqlalchemy import JSON, Double, Index, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base, BigId


class CommandRow(Base):
    __tablename__ = "commands"
    __table_args__ = (Index("ix_commands_robot_ts", "robot_id", "ts"),)

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    robot_id: Mapped[str] = mapped_column(String(64))
    command: Mapped[str] = mapped_column(String(64))
    args: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    source: Mapped[str] = mapped_column(String(120), default="rest")
    ts: Mapped[float] = mapped_column(Double)
    ttl_s: Mapped[float] = mapped_column(Double)
    status: Mapped[str] = mapped_column(String(16))
    reason: Mapped[str] = mapped_column(Text, default="")
    updated_at: Mapped[float] = mapped_column(Double)


class CommandAckRow(Base):
    __tablename__ = "command_acks"
    __table_args__ = (Index("ix_command_acks_command_id", "command_id"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    command_id: Mapped[str] = mapped_column(String(64))
    status: Mapped[str] = mapped_column(String(16))
    reason: Mapped[str] = mapped_column(Text, default="")
    ts: Mapped[float] = mapped_column(Double)
    received_ts: Mapped[float] = mapped_column(Double)
