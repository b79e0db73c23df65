"""The coverage planner: split an area among robots and give each a boustrophedon (lawn-mower) path.

Pure geometry on shapely; no I/O. The steps:

1. The *workable* region is the area, inside the site boundary shrunk by ``inset_m`` (geofence margin +
   robot radius), minus the keep-outs grown by the same band. Paths stay inside it and the sweep covers it.
2. It is cut into one part per robot by lines across the long axis of its minimum rotated rectangle, each
   cut placed (by bisection) so that every part has the same area: the same work at the same sweep width.
3. Each part gets lanes parallel to the cuts (for slices of an area cut across its long axis these run
   along the slices' long sides: few turns; one robot's lanes run along the area's long side),
   ``sweep_width * (1 - overlap)`` apart, swept in the order of the cuts (robot i from cut i-1 towards
   cut i). Lanes split by a keep-out are joined along a boundary ring, never across a hole.

Separation (docs/missions.md): the lanes of robot i within ``min_separation + tracking margin`` of cut i
(its *tail*) are the last it sweeps, the lanes of robot i+1 that near the same cut (its *head*) the first.
Robot i may start its tail only once robot i+1 has finished its head: the mission service holds it until
then. Every other pair of legs that can run at the same time is at least ``min_separation`` apart by
construction; :func:`concurrent_clearance` measures it.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import shapely
from shapely import affinity
from shapely.geometry import LineString, MultiLineString, MultiPolygon, Point, Polygon, box
from shapely.geometry.base import BaseGeometry
from shapely.ops import substring, unary_union

#: how far a robot may stray sideways from its lane (sets the width of the shared band at a cut)
TRACKING_MARGIN_M = 0.1
MAX_WAYPOINTS = 500


class PlanError(ValueError):
    """The request cannot be planned; ``code`` is the API's machine-readable reason."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass
class PartPlan:
    """One robot's share: its polygon, its path and where the separation rule splits that path."""

    index: int
    polygon: BaseGeometry
    path: list[tuple[float, float]]
    #: path[:head_end] is the head (near the previous cut): swept first
    head_end: int = 0
    #: path[tail_start:] is the tail (near the next cut): swept only once the next robot's head is done
    tail_start: int = 0
    area_m2: float = 0.0
    length_m: float = 0.0


@dataclass
class CoveragePlan:
    workable: BaseGeometry
    parts: list[PartPlan]
    angle_rad: float
    lane_spacing_m: float
    cuts: list[float] = field(default_factory=list)

    @property
    def area_m2(self) -> float:
        return float(self.workable.area)


def workable_region(
    area: BaseGeometry, boundary: BaseGeometry | None, keepouts: list[BaseGeometry], inset_m: float
) -> BaseGeometry:
    """The area the robots may sweep: inside the (inset) boundary, away from the (grown) keep-outs."""
    region = area
    if boundary is not None:
        region = region.intersection(boundary.buffer(-inset_m, join_style="mitre"))
    if keepouts:
        region = region.difference(unary_union([k.buffer(inset_m, join_style="mitre") for k in keepouts]))
    return region.buffer(0)


def _long_axis_angle(geom: BaseGeometry) -> float:
    """Direction of the long side of the minimum rotated rectangle (radians)."""
    rect = geom.minimum_rotated_rectangle
    if not isinstance(rect, Polygon):
        return 0.0
    xs, ys = rect.exterior.coords.xy
    edges = [(xs[i + 1] - xs[i], ys[i + 1] - ys[i]) for i in range(2)]
    dx, dy = max(edges, key=lambda e: math.hypot(*e))
    return math.atan2(dy, dx)


def _slab(lo: float, hi: float, bounds: tuple[float, float, float, float]) -> Polygon:
    """The band lo <= u < hi (rotated frame: u is x) over the region's bounds."""
    _, miny, _, maxy = bounds
    return box(lo, miny - 1.0, hi, maxy + 1.0)


def _split_equal(region: BaseGeometry, n: int) -> list[float]:
    """Cut positions (in u) giving n slabs of equal area, by bisection on each cut."""
    minx, _, maxx, _ = region.bounds
    total = region.area
    cuts: list[float] = []
    for k in range(1, n):
        target = total * k / n
        lo, hi = minx, maxx
        while hi - lo > 1e-6:  # a micrometre: far below any sweep width
            mid = (lo + hi) / 2
            if region.intersection(_slab(minx - 1.0, mid, region.bounds)).area < target:
                lo = mid
            else:
                hi = mid
        cuts.append((lo + hi) / 2)
    return cuts


def _polygons(geom: BaseGeometry) -> list[Polygon]:
    if isinstance(geom, Polygon):
        return [geom] if not geom.is_empty else []
    if isinstance(geom, MultiPolygon):
        return [g for g in geom.geoms if not g.is_empty]
    return [g for g in getattr(geom, "geoms", []) if isinstance(g, Polygon) and not g.is_empty]


def _segments(geom: BaseGeometry) -> list[LineString]:
    if isinstance(geom, LineString):
        return [geom] if geom.length > 0 else []
    if isinstance(geom, MultiLineString):
        return [g for g in geom.geoms if g.length > 0]
    return [g for g in getattr(geom, "geoms", []) if isinstance(g, LineString) and g.length > 0]


def _connect(
    a: tuple[float, float],
    b: tuple[float, float],
    part: BaseGeometry,
    region: BaseGeometry | None = None,
    inside: BaseGeometry | None = None,
) -> list[tuple[float, float]]:
    """From a to b inside the part: straight when that stays inside, else along a ring both lie on (of the
    part, or of the whole region when a keep-out cuts the part in two). ``inside``: the part grown by a
    micrometre and prepared (:func:`_inside`), built once per part rather than once per step."""
    if (inside if inside is not None else _inside(part)).contains(LineString([a, b])):
        return [b]
    for poly in _polygons(part) + (_polygons(region) if region is not None else []):
        for ring in [poly.exterior, *poly.interiors]:
            if ring.distance(Point(a)) < 1e-6 and ring.distance(Point(b)) < 1e-6:
                da, db = ring.project(Point(a)), ring.project(Point(b))
                forward = (db - da) % ring.length
                if forward <= ring.length / 2:
                    arc = _walk(ring, da, forward)
                else:
                    arc = list(reversed(_walk(ring, db, ring.length - forward)))
                return [*arc[1:-1], b]
    return [b]  # a and b on different rings: nothing shorter to follow (rare; see docs/missions.md)


def _inside(part: BaseGeometry) -> BaseGeometry:
    """The part grown by a micrometre (a step along its edge counts as inside), prepared for many tests."""
    grown = part.buffer(1e-6)
    shapely.prepare(grown)
    return grown


def _walk(ring: BaseGeometry, start: float, length: float) -> list[tuple[float, float]]:
    """Points along the ring from ``start`` for ``length`` (wrapping past the ring's start)."""
    end = start + length
    if end <= ring.length:
        pieces = [substring(ring, start, end)]
    else:
        pieces = [substring(ring, start, ring.length), substring(ring, 0.0, end - ring.length)]
    pts: list[tuple[float, float]] = []
    for piece in pieces:
        coords = [(float(x), float(y)) for x, y in piece.coords] if hasattr(piece, "coords") else []
        pts.extend(coords if not pts else coords[1:])
    return pts


def _lanes(
    part: BaseGeometry, spacing: float, lo: float, hi: float, ascending: bool
) -> list[list[tuple[float, float]]]:
    """Lanes (in the rotated frame, parallel to the cuts: constant u) over the part, each a list of segments'
    end points in sweep order, the segments of one lane alternating in direction with the lane index."""
    width = hi - lo
    count = max(1, math.ceil(width / spacing - 1e-9))
    step = width / count
    us = [lo + step * (i + 0.5) for i in range(count)]
    if not ascending:
        us.reverse()
    miny, maxy = part.bounds[1] - 1.0, part.bounds[3] + 1.0
    lanes: list[list[tuple[float, float]]] = []
    for u in us:
        segs = _segments(part.intersection(LineString([(u, miny), (u, maxy)])))
        if not segs:
            continue
        flip = len(lanes) % 2 == 1
        segs.sort(key=lambda s: min(s.coords[0][1], s.coords[-1][1]), reverse=flip)
        pts: list[tuple[float, float]] = []
        for s in segs:
            (x0, y0), (x1, y1) = s.coords[0], s.coords[-1]
            a, b = ((x0, y0), (x1, y1)) if (y0 <= y1) != flip else ((x1, y1), (x0, y0))
            pts.extend([(float(a[0]), float(a[1])), (float(b[0]), float(b[1]))])
        lanes.append(pts)
    return lanes


def plan_coverage(
    region: BaseGeometry,
    robots: int,
    sweep_width_m: float,
    overlap: float = 0.0,
    min_separation_m: float = 0.3,
) -> CoveragePlan:
    """Plan ``robots`` parts of equal area over ``region`` (see :func:`workable_region`), one path each."""
    if robots < 1:
        raise PlanError("no_robots", "a coverage mission needs at least one robot")
    if not sweep_width_m > 0:
        raise PlanError("bad_sweep_width", "sweep_width_m must be > 0")
    if not 0.0 <= overlap < 0.9:
        raise PlanError("bad_overlap", "overlap must be in [0, 0.9)")
    if region.is_empty or region.area < sweep_width_m**2:
        raise PlanError("area_empty", "nothing to sweep: the area is empty inside the site's fence and keep-outs")
    spacing = sweep_width_m * (1.0 - overlap)
    angle = _long_axis_angle(region)
    if robots == 1:  # no cuts: lanes (lines of constant u) along the long side, for the fewest turns
        angle += math.pi / 2
    origin = (0.0, 0.0)
    # rotated frame: u along the long axis (cuts are lines of constant u)
    rotated = affinity.rotate(region, -angle, origin=origin, use_radians=True)
    cuts = _split_equal(rotated, robots)
    minx, _, maxx, _ = rotated.bounds
    edges = [minx, *cuts, maxx]
    sep = min_separation_m + TRACKING_MARGIN_M
    # a part's lanes lie at least half its lane step inside its cuts: that much of ``sep`` is already there
    half_steps = [(hi - lo) / max(1, math.ceil((hi - lo) / spacing - 1e-9)) / 2 for lo, hi in itertools.pairwise(edges)]
    parts: list[PartPlan] = []
    for i in range(robots):
        lo, hi = edges[i], edges[i + 1]
        near_lo = sep - half_steps[i - 1] if i > 0 else 0.0
        near_hi = sep - half_steps[i + 1] if i < robots - 1 else 0.0
        piece = rotated.intersection(_slab(lo, hi, rotated.bounds)).buffer(0)
        lanes = _lanes(piece, spacing, lo, hi, ascending=True)
        inside = _inside(piece)
        path: list[tuple[float, float]] = []
        head_end, tail_start = 0, -1
        for n, lane in enumerate(lanes, 1):
            u, first = lane[0][0], len(path)
            path.extend(_connect(path[-1], lane[0], piece, rotated, inside) if path else [lane[0]])
            for a, b in itertools.pairwise(lane):
                if a != b:
                    path.extend(_connect(a, b, piece, rotated, inside))
            if len(path) > MAX_WAYPOINTS:  # refused as soon as it is too long: never built to the end
                raise PlanError(
                    "too_many_waypoints",
                    f"part {i} needs more than {MAX_WAYPOINTS} waypoints ({len(path)} after {n} of its "
                    f"{len(lanes)} lanes): widen the sweep or use more robots",
                )
            if i > 0 and u - lo < near_lo:
                head_end = len(path)
            if i < robots - 1 and hi - u < near_hi and tail_start < 0:
                tail_start = first
        if tail_start < 0:
            tail_start = len(path)
        cos_a, sin_a = math.cos(angle), math.sin(angle)
        world = [(x * cos_a - y * sin_a, x * sin_a + y * cos_a) for x, y in path]
        parts.append(
            PartPlan(
                index=i,
                polygon=affinity.rotate(piece, angle, origin=origin, use_radians=True),
                path=world,
                head_end=head_end,
                tail_start=tail_start,
                area_m2=float(piece.area),
                length_m=float(LineString(world).length) if len(world) > 1 else 0.0,
            )
        )
    return CoveragePlan(workable=region, parts=parts, angle_rad=angle, lane_spacing_m=spacing, cuts=cuts)


def swept(path: list[tuple[float, float]], sweep_width_m: float) -> BaseGeometry:
    """The strip a robot sweeps along ``path`` (positions it went through, or planned)."""
    if not path:
        return Polygon()
    if len(path) == 1:
        return Point(path[0]).buffer(sweep_width_m / 2)
    return LineString(path).buffer(sweep_width_m / 2, cap_style="round")


def _line(points: list[tuple[float, float]]) -> BaseGeometry:
    if not points:
        return LineString()
    return LineString(points) if len(points) > 1 else Point(points[0])


def concurrent_clearance(plan: CoveragePlan) -> float:
    """The smallest distance between legs of two robots that the separation rule lets run at the same time.

    Robot i starts its tail only once robot i+1 has reached ``path[head_end]``; every other pair may."""
    worst = math.inf
    parts = plan.parts
    for i, a in enumerate(parts):
        for j in range(i + 1, len(parts)):
            b = parts[j]
            if j == i + 1:
                pairs = [
                    (a.path[: a.tail_start], b.path),  # i before its tail: anything of i+1
                    # i's tail (from where it waited) once i+1 has reached the first point after its head
                    (a.path[max(a.tail_start - 1, 0) :], b.path[b.head_end :]),
                ]
            else:
                pairs = [(a.path, b.path)]
            for pa, pb in pairs:
                if pa and pb:
                    worst = min(worst, float(_line(pa).distance(_line(pb))))
    return worst
