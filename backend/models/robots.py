"""Robots the server has seen."""

from __future__ import annotations

from typing import Any

from sqlalchemy import JSON, Boolean, Double, String
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base


class Robot(Base):
    __tablename__ = "robots"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    legacy: Mapped[bool] = mapped_column(Boolean, default=False)
    agent_version: Mapped[str] = mapped_column(String(120), default="")
    capabilities: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    first_seen: Mapped[float] = mapped_column(Double)
    last_seen: Mapped[float | None] = mapped_column(Double, nullable=True)
    online: Mapped[bool] = mapped_column(Boolean, default=False)
    #: robots on the old framework: "shared" (the seed's code: robot/control/commands) or "own" topic
    legacy_listens_on: Mapped[str] = mapped_column(String(8), default="shared", server_default="shared")
