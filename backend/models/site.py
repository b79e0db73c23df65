"""The site (the pool's boundary, keep-outs, base stations and wall tags): every version ever set is kept."""

from __future__ import annotations

from typing import Any

from sqlalchemy import JSON, Double, Integer, String
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base


class SiteVersionRow(Base):
    """One version of the site. The newest is the current one; ``site`` NULL is "no site" (no fence), a state
    of its own that robots are told about. The primary key makes two replicas' concurrent edits collide."""

    __tablename__ = "site_versions"

    version: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    site: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    #: ``setting`` (seeded from FLEET_POOL_BOUNDARY on the first start) or ``api`` (PUT/DELETE /api/site)
    source: Mapped[str] = mapped_column(String(16))
    updated_by: Mapped[str] = mapped_column(String(160))
    updated_at: Mapped[float] = mapped_column(Double)
    #: the robots' safety filter settings (fleet_protocol.AvoidanceSettings); NULL (versions before 0017): defaults
    avoidance: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
