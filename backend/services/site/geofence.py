"""The server's side of the geofence: the site's geometry checked when an admin sets it, and goals checked
against it before they are sent (422 ``geofence``: a goal the robot would refuse never goes out).

The rule for a goal is the robot's own, one class for both (fleet_common/geofence.py, ``SafeRegion``): goals
and path points must lie in the *safe region*, the boundary moved ``geofence_margin_m`` inwards minus every
keep-out grown by the same margin, and a path's legs must stay in it; the refusals have the same words. The
robot checks again (with its own position) when it starts.
"""

from __future__ import annotations

from typing import Any

from shapely.geometry import Polygon
from shapely.validation import explain_validity

from backend.core.errors import ServiceError
from fleet_common.geofence import SafeRegion
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


class ServerFence(SafeRegion):
    """A site's safe region for goal checks (built once per site version): ``goal_problem(command, args)``,
    ``point_problem``, ``path_problem`` are fleet_common's, the robot's own rule."""

    def __init__(self, site: Site) -> None:
        super().__init__(site.boundary, site.keepouts, site.geofence_margin_m)
