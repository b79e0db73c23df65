"""Missions: a mission (its plan and progress as JSON), every state transition, and its events."""

from __future__ import annotations

from typing import Any

from sqlalchemy import JSON, Double, Index, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base, BigId


class MissionRow(Base):
    """A mission: draft -> running <-> paused -> completed | aborted | failed. ``plan`` holds the parts and
    paths; ``progress`` each robot's leg state and its swept track (where it actually went)."""

    __tablename__ = "missions"
    __table_args__ = (Index("ix_missions_state", "state"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    type: Mapped[str] = mapped_column(String(32))
    state: Mapped[str] = mapped_column(String(16))
    reason: Mapped[str] = mapped_column(Text, default="")
    robots: Mapped[list[str]] = mapped_column(JSON, default=list)
    params: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    plan: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    progress: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    created_by: Mapped[str] = mapped_column(String(160))
    created_at: Mapped[float] = mapped_column(Double)
    updated_at: Mapped[float] = mapped_column(Double)
    started_at: Mapped[float | None] = mapped_column(Double, nullable=True)
    ended_at: Mapped[float | None] = mapped_column(Double, nullable=True)
    #: seconds spent running before the current run (pauses do not count)
    run_s: Mapped[float] = mapped_column(Double, default=0.0)
    #: the server replica that runs it (a row lease, docs/missions.md "Replicas"), and when it last renewed
    owner: Mapped[str | None] = mapped_column(String(64), nullable=True)
    heartbeat_at: Mapped[float | None] = mapped_column(Double, nullable=True)
    #: pause or abort asked through another replica, for the owner to apply: {action, actor, reason, by, ts}
    requested: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)


class MissionTransitionRow(Base):
    """Every state change of a mission, with when, who (``system`` for the server itself) and why."""

    __tablename__ = "mission_transitions"
    __table_args__ = (Index("ix_mission_transitions_mission", "mission_id"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    mission_id: Mapped[str] = mapped_column(String(36))
    ts: Mapped[float] = mapped_column(Double)
    from_state: Mapped[str] = mapped_column(String(16))
    to_state: Mapped[str] = mapped_column(String(16))
    actor: Mapped[str] = mapped_column(String(160))
    reason: Mapped[str] = mapped_column(Text, default="")


class MissionEventRow(Base):
    """What happened during a mission: dropouts, re-plans, waits for separation, robots done."""

    __tablename__ = "mission_events"
    __table_args__ = (Index("ix_mission_events_mission", "mission_id"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    mission_id: Mapped[str] = mapped_column(String(36))
    ts: Mapped[float] = mapped_column(Double)
    kind: Mapped[str] = mapped_column(String(32))
    robot_id: Mapped[str | None] = mapped_column(String(64), nullable=True)
    detail: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)


__all__ = ["MissionEventRow", "MissionRow", "MissionTransitionRow"]
