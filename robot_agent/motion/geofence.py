"""The geofence on the robot: the site's boundary and keep-outs, shrunk by the margin, as shapely geometry.

The *safe region* is the boundary moved ``geofence_margin_m`` inwards, minus every keep-out grown by the same
margin: goals and path points must lie in it. That rule is fleet_common/geofence.py's, shared with the
server (which refuses the same goals in the same words); this file adds what only the robot checks. Motion
may use half of the margin more (the *motion region*), so that a controller holding a goal at the edge of
the safe region is not stopped by its own noise: every motion is stopped before its stopping point would
leave the motion region (or, for a robot already outside, unless it brings the robot closer). The fence
itself, the boundary, is never reached while driven. ``site: null`` (published by the server) means no
fence; a robot that has heard nothing yet knows no site and refuses goals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fleet_common.geofence import SafeRegion
from fleet_protocol.motion import Site, SiteMessage

if TYPE_CHECKING:
    from shapely.geometry.base import BaseGeometry

# shapely (and numpy with it) is imported when the first fence arrives, not when the agent starts: an agent
# without a site never pays its memory (tests/robot_agent/motors/test_gpio.py checks the lazy imports).


@dataclass(frozen=True, slots=True)
class SiteState:
    """What the robot knows of the site: nothing yet (``received`` False), no fence, or a fence."""

    received: bool
    version: int | None
    fence: Geofence | None

    @classmethod
    def unknown(cls) -> SiteState:
        return cls(False, None, None)

    @classmethod
    def from_message(cls, msg: SiteMessage) -> SiteState:
        return cls(True, msg.version, None if msg.site is None else Geofence(msg.site))

    def describe(self) -> str:
        if not self.received:
            return "no site received"
        return f"site v{self.version}" + ("" if self.fence else " (no fence)")


class Geofence(SafeRegion):
    """The site's fence on the robot: the goal rule (point_problem, path_problem, goal_problem, and ``safe``)
    is the server's own, from fleet_common; the motion region and the checks of a motion are the robot's."""

    def __init__(self, site: Site) -> None:
        super().__init__(site.boundary, site.keepouts, site.geofence_margin_m)  # imports shapely
        import shapely
        from shapely import prepared

        self._contains_xy = shapely.contains_xy
        self.site = site
        region: BaseGeometry = self.boundary.buffer(-self.margin / 2)
        for k in self.keepouts:
            region = region.difference(k.buffer(self.margin / 2))
        self.motion_region = region
        self._region_prepared = prepared.prep(region)
        shapely.prepare(region)  # contains_xy on the region itself: no Point made per control step

    # -- where a goal may be: point_problem, path_problem (SafeRegion), and the way there from here ----------
    def leg_problem(self, start: tuple[float, float], goal: tuple[float, float]) -> str | None:
        """Why the straight way from ``start`` to a goal is blocked: a keep-out in between. A start outside
        the safe region (a robot that drifted) is fine: it is on its way back."""
        if start == goal:
            return None
        line = self._LineString([start, goal])
        for i, k in enumerate(self.keepouts):
            if line.intersects(k):
                return f"the way to the goal crosses keep-out {i}"
        return None

    # -- whether a motion may go on -------------------------------------------------------------------
    def distance_outside(self, x: float, y: float) -> float:
        """0 inside the motion region, else how far outside it (metres)."""
        if self._contains_xy(self.motion_region, x, y):
            return 0.0
        return float(self.motion_region.distance(self._Point(x, y)))

    def outside_safe(self, x: float, y: float) -> bool:
        return not self._safe_prepared.contains(self._Point(x, y))

    def motion_problem(self, x: float, y: float, vx: float, vy: float, horizon_s: float) -> str | None:
        """Why moving at (vx, vy) m/s from (x, y) must stop: the point it would reach within ``horizon_s``
        (its stopping distance) leaves the safe region, and for a robot already outside, does not bring
        it closer."""
        speed = math.hypot(vx, vy)
        if speed < 1e-4:
            return None
        px, py = x + vx * horizon_s, y + vy * horizon_s
        ahead = self.distance_outside(px, py)
        if ahead == 0.0:
            # Both ends inside: a thin keep-out in between could still be crossed within the horizon.
            clear = self._region_prepared.contains(self._LineString([(x, y), (px, py)]))
            if clear or self.distance_outside(x, y) > 0:
                return None
            return f"a keep-out lies within the stopping distance ({speed * horizon_s:.3f} m)"
        here = self.distance_outside(x, y)
        if here > 0 and ahead < here:
            return None  # outside already, and heading back in
        return (
            f"would come within {self.margin / 2:.3f} m of the fence within its stopping distance "
            f"({speed * horizon_s:.3f} m)"
        )
