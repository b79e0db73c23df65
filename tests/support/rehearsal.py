"""Rehearsals without a server: a draft mission planned by the real mission service on the twin's stand-ins
(backend/services/rehearsal/server.py), and the input a live server would hand the twin."""

from __future__ import annotations

import asyncio
import time
from typing import Any

from pydantic import TypeAdapter

from backend.schemas.missions import MissionCreate
from backend.services.missions.record import Mission
from backend.services.rehearsal import RehearsalInput, RobotStart
from backend.services.rehearsal import server as twin
from fleet_protocol import AvoidanceSettings, Site, SiteMessage
from fleet_protocol.motion import default_pool_site


def draft(body: dict[str, Any], starts: list[RobotStart], site: Site | None = None) -> Mission:
    """The draft mission ``body`` (as POST /api/missions takes it), planned with the robots at ``starts``."""
    site = site or default_pool_site()

    async def create() -> Mission:
        registry = twin.TwinRegistry([r.robot_id for r in starts])
        for r in starts:
            registry.on_fix(r.robot_id, time.time(), {"x": r.x, "y": r.y, "yaw": r.yaw})
        service = twin.twin_mission_service(
            registry=registry,
            commands=None,
            site=twin.TwinSite(site, 1),
            hub=twin.TwinHub(),
            server_id="test",
            clock=time.time,
        )
        created = await service.create(TypeAdapter(MissionCreate).validate_python(body), "test")
        return service.missions[created.id]

    return asyncio.run(create())


def rehearsal_input(
    body: dict[str, Any], starts: list[RobotStart], site: Site | None = None, limit_s: float = 600.0
) -> RehearsalInput:
    site = site or default_pool_site()
    message = SiteMessage(version=1, site=site, avoidance=AvoidanceSettings())
    return RehearsalInput(draft(body, starts, site), message.model_dump(mode="json"), starts, limit_s)
