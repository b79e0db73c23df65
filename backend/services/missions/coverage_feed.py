"""The swept area on the live socket: what the dashboard's map draws of a mission comes from the server,
pushed, never polled and never recomputed in the browser (issue 30).

A mission's plan (its parts: each robot's polygon and path) goes out with every ``mission`` message. Its
swept area (the GeoJSON the coverage route serves, outlined on the planner pool) goes out as a
``mission_coverage`` message whenever it changed, checked every ``PUSH_S``; a client that connects gets the
live missions and their swept areas in its snapshot. docs/api.md, "WebSocket `/ws`".
"""

from __future__ import annotations

from typing import Any

import orjson
from shapely.geometry import Polygon

from backend.core.errors import ServiceError
from backend.services.missions.book import ENDED, MissionBook, log
from backend.services.missions.record import mission_public
from backend.services.missions.state import geojson
from backend.services.missions.sweep import SweptView

#: how often the swept areas are looked at (a push only when one changed)
PUSH_S = 1.0
#: a mission's state in which the map shows it (an ended one stays until it leaves the book)
SHOWN = ("running", "paused")


class CoverageFeed(MissionBook):
    async def push_coverage(self) -> int:
        """Push each shown mission's swept area that changed since it was last pushed, and the final one of a
        mission that just ended. Returns how many went out. The outline is built on the planner pool; when
        the pool is busy the mission waits for the next look."""
        pushed = self.swept_pushed
        sent = 0
        for m in list(self.missions.values()):
            if m.state not in SHOWN and m.id not in pushed:
                continue
            held = m.coverage
            if m.owner != self.server_id and held.deferred and held.geojson_cache is None:
                # another replica runs it: its grid is never built here in the background (its owner's
                # figure stands); its swept area goes out once a client asked for it (GET .../coverage)
                continue
            try:
                body = await self.coverage_geojson(m.id)
            except ServiceError as exc:  # planner busy or stopping: the next look
                log.debug("mission %s: swept area not pushed: %s", m.id, exc.detail)
                continue
            if m.state in ENDED:
                last = pushed.pop(m.id, None)
                if last == body:
                    continue
            elif pushed.get(m.id) == body:
                continue
            else:
                pushed[m.id] = body
            self._hub.publish_control(
                {
                    "type": "mission_coverage",
                    "mission_id": m.id,
                    "state": m.state,
                    "covered_fraction": round(m.coverage.fraction, 4),
                    "geometry": orjson.Fragment(body),
                }
            )
            sent += 1
        return sent

    async def coverage_geojson(self, mission_id: str) -> bytes:
        """The swept area as GeoJSON, outlined on the planner pool once per change of the grid (pushed at
        most every PUSH_S; the outline's work is bounded by the grid's cells, not by the tracks). A mission
        with only its row's figures (ended, mirrored) keeps the outline it was given: its row's tracks are
        what they were until a newer row replaces it."""
        m = self.get(mission_id)
        held = m.coverage
        if held.deferred and held.geojson_cache is not None:
            return held.geojson_cache[1]
        cov = await self._coverage_ready(m, queued=False)
        cached = cov.geojson_cache
        if cached is not None and cached[0] == cov.version:
            return cached[1]
        version = cov.version
        body = await self.planner.run(swept_geojson, cov.view())
        cov.geojson_cache = (version, body)
        if m.coverage is held and held.deferred:
            held.geojson_cache = (held.version, body)
        return body

    def live_snapshot(self) -> dict[str, Any]:
        """What a client that just connected needs to draw the live missions: each shown mission (without its
        events and transitions) and the swept area last pushed for it."""
        pushed = self.swept_pushed
        shown = [m for m in self.missions.values() if m.state in SHOWN]
        return {
            "missions": [mission_public(m).model_dump(mode="json", exclude={"events", "transitions"}) for m in shown],
            "coverage": {m.id: orjson.Fragment(pushed[m.id]) for m in shown if m.id in pushed},
        }


def swept_geojson(view: SweptView | None) -> bytes:
    """The swept area's GeoJSON geometry (on the planner pool): empty for a mission without a region."""
    return orjson.dumps(geojson(view.geometry() if view is not None else Polygon()))
