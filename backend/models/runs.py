"""Experiment runs (issue 19): a named stretch of time over some robots, and the markers set during it.

The telemetry, commands and events of a run are not copied: a run is the index (robots + start/end) over
the tables that hold them. Camera frames are kept on disk in a per-run store (services/runs/frames.py).
``tag_index`` / ``robot_index`` hold ``|a|b|`` so a search is one LIKE on any database.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import JSON, BigInteger, Boolean, Double, Index, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base, BigId


class RunRow(Base):
    __tablename__ = "runs"
    __table_args__ = (Index("ix_runs_started_at", "started_at"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    name: Mapped[str] = mapped_column(String(200))
    notes: Mapped[str] = mapped_column(Text, default="")
    tags: Mapped[list[str]] = mapped_column(JSON, default=list)
    tag_index: Mapped[str] = mapped_column(Text, default="|")
    operator: Mapped[str] = mapped_column(String(160))
    robots: Mapped[list[str]] = mapped_column(JSON, default=list)
    robot_index: Mapped[str] = mapped_column(Text, default="|")
    started_at: Mapped[float] = mapped_column(Double)
    ended_at: Mapped[float | None] = mapped_column(Double, nullable=True)
    site_version: Mapped[int] = mapped_column(BigInteger, default=0)
    #: robot id -> {agent_version, protocol_version, capabilities, sensors} at the start
    agents: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    #: camera frames kept per second and robot (0: none)
    frame_rate: Mapped[float] = mapped_column(Double, default=5.0)
    frames: Mapped[int] = mapped_column(BigInteger, default=0)
    frame_bytes: Mapped[int] = mapped_column(BigInteger, default=0)
    #: set when frame recording stopped because the store's quota would be exceeded
    frames_stopped: Mapped[bool] = mapped_column(Boolean, default=False)
    frames_stopped_reason: Mapped[str] = mapped_column(Text, default="")
    #: the mission that opened the run (migration 0016; null: started by hand, or recorded before)
    mission_id: Mapped[str | None] = mapped_column(String(64), nullable=True)


class MarkerRow(Base):
    """An annotation at a moment of a run ("tag 3 fell"), optionally about one robot."""

    __tablename__ = "run_markers"
    __table_args__ = (Index("ix_run_markers_run_ts", "run_id", "ts"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    run_id: Mapped[int] = mapped_column(BigInteger)
    ts: Mapped[float] = mapped_column(Double)
    text: Mapped[str] = mapped_column(Text)
    robot_id: Mapped[str | None] = mapped_column(String(64), nullable=True)
    author: Mapped[str] = mapped_column(String(160), default="")
    created_at: Mapped[float] = mapped_column(Double)
