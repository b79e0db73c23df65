"""The geofence's rule for goals, shared by the server and the robot: where a goal or a path may lie.

Shared so that the server refuses (422 ``geofence``) exactly the goals the robot would refuse, in the same
words: the operator reads one reason whichever side said no, and the tests and API clients match on it. The
robot still checks again when a goal starts (with its own position), and keeps its motion checks (the
*motion region*, stopping distances) in robot_agent/motion/geofence.py; the server keeps its checks of an
admin's site (backend/services).

The rule: goals and path points must lie in the *safe region*, the boundary moved ``margin`` inwards minus
every keep-out grown by the same margin, and a path's legs (with the closing leg of a loop) must stay in it.

Plain coordinates in (a boundary as (x, y) pairs, keep-outs as lists of them), no project package imported
(fleet_common is a leaf). shapely, and numpy with it, is imported when the first region is built, not when
this module is: an agent without a site never pays its memory (tests/robot_agent/motors/test_gpio.py).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from shapely.geometry import Polygon
    from shapely.geometry.base import BaseGeometry

Coords = Sequence[Sequence[float]]  # a polygon's corners or a path's points: (x, y) each


class SafeRegion:
    """A site's safe region for goals, built once (the keep-outs grown by the margin and every region
    prepared here, not on each check).

    ``boundary`` and ``keepouts`` are the site's polygons as given, ``grown_keepouts`` the keep-outs grown by
    the margin, ``safe`` the safe region (shapely geometry)."""

    def __init__(self, boundary: Coords, keepouts: Sequence[Coords] = (), margin: float = 0.0) -> None:
        from shapely import prepared
        from shapely.geometry import LineString, Point, Polygon

        self._Point, self._LineString = Point, LineString
        self.margin = margin
        self.boundary: Polygon = Polygon(boundary)
        self.keepouts: list[Polygon] = [Polygon(k) for k in keepouts]
        self.grown_keepouts: list[BaseGeometry] = [k.buffer(margin) for k in self.keepouts]
        safe: BaseGeometry = self.boundary.buffer(-margin)
        for k in self.grown_keepouts:
            safe = safe.difference(k)
        self.safe = safe
        self._boundary_prepared = prepared.prep(self.boundary)
        self._grown_prepared = [prepared.prep(k) for k in self.grown_keepouts]
        self._safe_prepared = prepared.prep(safe)

    def point_problem(self, x: float, y: float) -> str | None:
        """Why (x, y) may not be a goal, or None."""
        p = self._Point(x, y)
        if not self._boundary_prepared.contains(p):
            return f"({x:.3f}, {y:.3f}) is outside the boundary"
        for i, k in enumerate(self._grown_prepared):
            if k.contains(p):
                return f"({x:.3f}, {y:.3f}) is inside keep-out {i} (or within its {self.margin} m margin)"
        if not self._safe_prepared.contains(p):
            return f"({x:.3f}, {y:.3f}) is within the {self.margin} m margin of the boundary"
        return None

    def path_problem(self, points: Coords, closed: bool = False) -> str | None:
        """Why a polyline through ``points`` (closed: back to the first, for more than two points) may not be
        followed: a point or a leg leaves the safe region; or None."""
        pts = [(float(p[0]), float(p[1])) for p in points]
        for i, (x, y) in enumerate(pts):
            why = self.point_problem(x, y)
            if why is not None:
                return f"waypoint {i}: {why}"
        legs = list(itertools.pairwise(pts))
        if closed and len(pts) > 2:
            legs.append((pts[-1], pts[0]))
        for i, (a, b) in enumerate(legs):
            if a != b and not self._safe_prepared.contains(self._LineString([a, b])):
                return f"the leg from waypoint {i} leaves the safe region (crosses a keep-out or the margin)"
        return None

    def goal_problem(self, command: str, args: Mapping[str, Any]) -> str | None:
        """Why a ``goto`` (args ``x``, ``y``) or ``follow_path`` (args ``waypoints``, ``loop``) goal may not be
        sent, or None. Any other command is not a goal: ValueError."""
        if command == "goto":
            return self.point_problem(float(args["x"]), float(args["y"]))
        if command == "follow_path":
            return self.path_problem(args["waypoints"], bool(args.get("loop")))
        raise ValueError(f"{command!r} is not a goal (goto or follow_path)")
