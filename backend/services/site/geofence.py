"""The server's side of the geofence: the site's geometry checked when an admin sets it, and goals checked
against it before they are sent (422 ``geofence``: a goal the robot would refuse never goes out).

The rule for a goal is the robot's own (robot_agent/motion/geofence.py): goals and path points must lie in
the *safe region*, the boundary moved ``geofence_margin_m`` inwards minus every keep-out grown by the same
margin, and a path's legs must stay in it. The robot checks again (with its own position) when it starts.
"""

from __future__ import annotations

import itertools
from typing import Any

from shapely import prepared
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.validation import explain_validity

from backend.core.errors import ServiceError
from fleet_protocol.motion import Site


class SiteRefused(ServiceError):
    """An admin's site that cannot be a pool: 422 with what is wrong and a ``code``; nothing is stored."""

    def __init__(self, detail: str, code: str) -> None:
        super().__init__(422, detail, code)


def _polygon(points: list[list[float]], what: str) -> Polygon:
    poly = Polygon(points)
    if not poly.is_valid:
        raise SiteRefused(
            f"{what} is not a simple polygon ({explain_validity(poly)}): its edges must not cross or touch",
            "bad_polygon",
        )
    if poly.area <= 0:
        raise SiteRefused(f"{what} has no area (its corners are on one line)", "bad_polygon")
    return poly


def check_site(site: dict[str, Any]) -> None:
    """Refuse (:class:`SiteRefused`) what the schema cannot say: polygons that cross themselves or have no
    area, keep-outs not inside the boundary, overlapping each other's ids among the tags."""
    boundary = _polygon(site["boundary"], "boundary")
    for i, points in enumerate(site.get("keepouts") or []):
        keepout = _polygon(points, f"keepout {i}")
        if not boundary.contains(keepout):
            raise SiteRefused(f"keepout {i} is not inside the boundary", "keepout_outside_boundary")
    seen: set[int] = set()
    for tag in site.get("tags") or []:
        if tag["id"] in seen:
            raise SiteRefused(f"tag id {tag['id']} appears twice: each wall tag has its own id", "duplicate_tag")
        seen.add(tag["id"])


class ServerFence:
    """A site's safe region for goal checks (built once per site version)."""

    def __init__(self, site: Site) -> None:
        self.margin = site.geofence_margin_m
        self.boundary = Polygon(site.boundary)
        self.keepouts = [Polygon(k).buffer(self.margin) for k in site.keepouts]
        safe: BaseGeometry = self.boundary.buffer(-self.margin)
        for k in self.keepouts:
            safe = safe.difference(k)
        self._safe = prepared.prep(safe)

    def point_problem(self, x: float, y: float) -> str | None:
        p = Point(x, y)
        if not self.boundary.contains(p):
            return f"({x:.3f}, {y:.3f}) is outside the boundary"
        for i, k in enumerate(self.keepouts):
            if k.contains(p):
                return f"({x:.3f}, {y:.3f}) is inside keep-out {i} (or within its {self.margin} m margin)"
        if not self._safe.contains(p):
            return f"({x:.3f}, {y:.3f}) is within the {self.margin} m margin of the boundary"
        return None

    def path_problem(self, points: list[tuple[float, float]], closed: bool) -> str | None:
        for i, (x, y) in enumerate(points):
            why = self.point_problem(x, y)
            if why is not None:
                return f"waypoint {i}: {why}"
        legs = list(itertools.pairwise(points))
        if closed and len(points) > 2:
            legs.append((points[-1], points[0]))
        for i, (a, b) in enumerate(legs):
            if a != b and not self._safe.contains(LineString([a, b])):
                return f"the leg from waypoint {i} leaves the safe region (crosses a keep-out or the margin)"
        return None

    def goal_problem(self, command: str, args: dict[str, Any]) -> str | None:
        """Why a checked goto/follow_path goal may not be sent, or None."""
        if command == "goto":
            return self.point_problem(float(args["x"]), float(args["y"]))
        points = [(float(p[0]), float(p[1])) for p in args["waypoints"]]
        return self.path_problem(points, bool(args.get("loop")))
