"""One mission's live state: each robot's path, legs and track, and the geometry of its progress.

A robot's path is sent as *legs* (``follow_path`` commands) that end at breakpoints: after its head (the
lanes near the previous robot's part, plus the step to its next lane) and before its tail (the lanes near
the next robot's part). The tail waits until the next robot has finished its head leg (its ``done`` ack):
the separation rule of backend/services/missions/coverage.py. Progress is measured from where the robots actually went:
their tracks (positions sampled while running), swept at the sweep width onto a grid point by point (sweep.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from shapely.geometry import LineString, MultiPolygon, Point, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.ops import unary_union

from backend.services.missions.coverage import CoveragePlan, PlanError, plan_coverage
from backend.services.missions.limits import check_coverage, estimate_coverage, region_corners
from backend.services.missions.sweep import SweptGrid, SweptView

#: a track point is kept when the robot moved this far since the previous one
TRACK_STEP_M = 0.02
#: a waypoint counts as passed when the robot came this close to it (display, resume)
PASS_RADIUS_M = 0.12
#: remaining area smaller than this share of a part is not worth re-planning
REPLAN_MIN_SHARE = 0.01
DEFAULT_SPEED_MPS = 0.15
#: beyond the separation and half a sweep: how far a stopped robot may drift while others sweep near it
KEEP_CLEAR_MARGIN_M = 0.15
#: track points a coverage update marks at most (the rest wait for the next): bounds a step's work on the loop
MAX_POINTS_PER_UPDATE = 2_000
#: a waiting or finished robot of a running mission is driven back to its place once it drifted this far
HOLD_DRIFT_M = 0.05
#: ... to within this
HOLD_TOLERANCE_M = 0.03

ACTIVE = ("pending", "moving", "waiting", "paused")


@dataclass
class MissionRobot:
    robot_id: str
    path: list[list[float]]
    #: path indices where a leg ends (exclusive), ascending; the last is len(path)
    breaks: list[int]
    #: the leg starting at ``gate_at`` waits for ``gate_robot`` to finish its first leg
    gate_at: int | None = None
    gate_robot: str | None = None
    polygon: list[list[list[float]]] = field(default_factory=list)
    area_m2: float = 0.0
    status: str = "pending"
    reason: str = ""
    #: the next waypoint to reach (legs completed up to here; or where it was when paused)
    index: int = 0
    #: furthest waypoint it passed near (progress display and resume)
    reached: int = 0
    leg_end: int = 0
    command_id: str | None = None
    track: list[list[float]] = field(default_factory=list)
    #: once ``index`` reaches this (its head leg acked done), the previous robot may start its tail
    head_pass: int = 0
    #: where a waiting or finished robot holds its place (against the current) while the mission runs
    hold_at: list[float] | None = None
    hold_command_id: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> MissionRobot:
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})

    @property
    def active(self) -> bool:
        return self.status in ACTIVE

    def next_leg(self) -> tuple[int, int] | None:
        """The leg to send from ``index``: (start, end); None when the path is done."""
        if self.index >= len(self.path):
            return None
        end = next((b for b in self.breaks if b > self.index), len(self.path))
        return self.index, end

    def observe(self, x: float, y: float) -> None:
        if not self.track or math.hypot(x - self.track[-1][0], y - self.track[-1][1]) >= TRACK_STEP_M:
            self.track.append([round(x, 4), round(y, 4)])
        limit = self.leg_end if self.status == "moving" else self.index
        j = max(self.reached, self.index)
        while j < min(limit, len(self.path)) and math.hypot(x - self.path[j][0], y - self.path[j][1]) < PASS_RADIUS_M:
            j += 1
        self.reached = j

    def remaining_m(self) -> float:
        pts = self.path[max(self.reached, self.index) :]
        return float(LineString(pts).length) if len(pts) > 1 else 0.0


def rings(geom: BaseGeometry) -> list[list[list[float]]]:
    """Exterior rings of a (multi)polygon as [x, y] lists (for the API and the map)."""
    polys = [geom] if isinstance(geom, Polygon) else list(getattr(geom, "geoms", []))
    return [[[round(x, 4), round(y, 4)] for x, y in p.exterior.coords] for p in polys if isinstance(p, Polygon)]


def _polygon_of(rings_: list[list[list[float]]]) -> BaseGeometry:
    polys = [Polygon(r) for r in rings_ if len(r) >= 3]
    return MultiPolygon(polys) if len(polys) > 1 else (polys[0] if polys else Polygon())


def robots_from_plan(order: list[str], plan: CoveragePlan) -> list[MissionRobot]:
    runs: list[MissionRobot] = []
    for i, (rid, part) in enumerate(zip(order, plan.parts, strict=True)):
        path = [[round(x, 4), round(y, 4)] for x, y in part.path]
        breaks = set()
        head_pass = min(part.head_end + 1, len(path)) if i > 0 and part.head_end > 0 else 0
        if head_pass:
            breaks.add(head_pass)
        gate_at = None
        if i < len(order) - 1 and part.tail_start < len(path) and plan.parts[i + 1].head_end > 0:
            gate_at = part.tail_start
            if gate_at > 0:
                breaks.add(gate_at)
        breaks.add(len(path))
        runs.append(
            MissionRobot(
                robot_id=rid,
                path=path,
                breaks=sorted(b for b in breaks if b > 0),
                gate_at=gate_at,
                gate_robot=order[i + 1] if gate_at is not None else None,
                polygon=rings(part.polygon),
                area_m2=round(part.area_m2, 4),
                head_pass=head_pass,
            )
        )
    return runs


def waypoint_robots(paths: dict[str, list[list[float]]]) -> list[MissionRobot]:
    return [MissionRobot(robot_id=rid, path=path, breaks=[len(path)]) for rid, path in paths.items()]


class Coverage:
    """The swept area of a mission's tracks over its workable region (sweep.py): each :meth:`update` marks
    only the track points added since the last one, so a step's work does not grow with the mission.

    Built with its grid (the region's cells and weights: up to a few hundred ms for a large area) on the
    planner pool when a mission starts. One read from its row (a restart, another replica's mirror), a
    draft's and an ended mission's have only their figures (``stored``), no grid and no geometry, until
    :func:`built_coverage` makes one on the pool: a row is never turned into geometry on the event loop."""

    def __init__(
        self,
        workable: list[list[list[float]]],
        holes: list[list[list[float]]],
        width_m: float,
        stored: tuple[float, dict[str, float]] | None = None,
    ) -> None:
        self.workable, self.holes, self.width = workable, holes, width_m
        self.region: BaseGeometry = Polygon()
        self.grid: SweptGrid | None = None
        self.fraction, self.per_robot = stored if stored is not None else (0.0, {})
        #: robot id -> its bit in the grid, the track points marked, the last of them (a mirror's check)
        self._bits: dict[str, int] = {}
        self._done: dict[str, int] = {}
        self._last: dict[str, list[float]] = {}
        #: track points marked by the last update (its work), and a count of the updates that marked any
        self.work = 0
        self.version = 0
        #: the swept area's GeoJSON (bytes) and the version it was drawn at (service.py)
        self.geojson_cache: tuple[int, bytes] | None = None
        self._stored = stored is not None
        if not self._stored and workable:
            self._build()

    def _build(self) -> None:
        region = _polygon_of(self.workable)
        if self.holes:
            region = region.difference(unary_union([Polygon(h) for h in self.holes if len(h) >= 3]))
        self.region = region
        if not region.is_empty:
            self.grid = SweptGrid(region, self.width)

    @property
    def deferred(self) -> bool:
        """Only its figures, its grid not built (yet): :func:`built_coverage`."""
        return self._stored and self.grid is None and bool(self.workable)

    def update(self, robots: list[MissionRobot], budget: int = MAX_POINTS_PER_UPDATE) -> None:
        """Mark the track points added since the last update (at most ``budget``: the rest wait for the next
        one). Nothing to do without a grid (no coverage mission, or a row's figures)."""
        self.work = 0
        grid = self.grid
        if grid is None:
            return
        for r in robots:
            done, n = self._done.get(r.robot_id, 0), len(r.track)
            if n <= done or budget <= 0:
                continue
            take = min(n, done + budget)
            bit = self._bits.setdefault(r.robot_id, len(self._bits) % 32)
            grid.add(bit, np.asarray(r.track[max(done - 1, 0) : take], dtype=float))
            self._done[r.robot_id], self._last[r.robot_id] = take, list(r.track[take - 1])
            self.work += take - done
            budget -= take - done
        if self.work:
            self.version += 1
            cell = grid.frame.cell_m2
            self.fraction = grid.covered / grid.total if grid.total > 0 else 0.0
            self.per_robot = {rid: grid.swept.get(bit, 0.0) * cell for rid, bit in self._bits.items()}

    def continues(self, robots: list[MissionRobot]) -> bool:
        """Whether ``robots`` (a newer row of the same plan) extend the tracks marked so far: the same robots
        with at least as many points, the last one marked where it was. O(robots)."""
        for rid, done in self._done.items():
            r = next((x for x in robots if x.robot_id == rid), None)
            if r is None or len(r.track) < done or (done and list(r.track[done - 1]) != self._last[rid]):
                return False
        return True

    def view(self) -> SweptView | None:
        """What is swept now, copied for the planner pool (None without a grid)."""
        return self.grid.view() if self.grid is not None else None

    def figures_only(self) -> Coverage:
        """Its figures without its grid (an ended mission's: the grid, up to 8 MB, is not kept for it)."""
        return Coverage(self.workable, self.holes, self.width, (self.fraction, dict(self.per_robot)))


def built_coverage(stored: Coverage, tracks: list[tuple[str, list[list[float]], int]]) -> Coverage:
    """A row's coverage with its grid, the first ``n`` points of each ``(robot id, track, n)`` marked: on the
    planner pool (its work grows with the tracks: once per mission read from a row)."""
    cov = Coverage(stored.workable, stored.holes, stored.width)
    robots = [MissionRobot(robot_id=rid, path=[], breaks=[], track=track[:n]) for rid, track, n in tracks]
    cov.update(robots, budget=sum(n for _, _, n in tracks))
    return cov


def replan(
    dropped: MissionRobot,
    survivors: list[MissionRobot],
    coverage: Coverage,
    overlap: float,
    min_sep: float,
    keep_clear: list[tuple[float, float]] | None = None,
) -> int:
    """Give the dropped robot's remaining area (its part minus what every track swept) to the survivors:
    a new part each, appended to their paths. Around ``keep_clear`` (where stopped robots of the mission
    are) a disc stays out of the new parts, so that nobody is sent to sweep into them. Returns how many
    survivors got work. (The mission service plans on its planner pool and hands over on the loop: the two
    halves, :func:`plan_takeover` and :func:`hand_over`.)"""
    view = coverage.view()
    if view is None:
        return 0
    return hand_over(
        dropped, survivors, takeover_of(view, dropped.polygon, len(survivors), overlap, min_sep, keep_clear)
    )


def takeover_of(
    view: SweptView,
    polygon: list[list[list[float]]],
    survivors: int,
    overlap: float,
    min_sep: float,
    keep_clear: list[tuple[float, float]] | None = None,
) -> CoveragePlan | None:
    """:func:`plan_takeover` less what ``view`` shows swept (its outline drawn here: on the planner pool)."""
    return plan_takeover(polygon, survivors, view.region, view.geometry(), view.width, overlap, min_sep, keep_clear)


def plan_takeover(
    polygon: list[list[list[float]]],
    survivors: int,
    region: BaseGeometry,
    swept: BaseGeometry,
    width: float,
    overlap: float,
    min_sep: float,
    keep_clear: list[tuple[float, float]] | None = None,
) -> CoveragePlan | None:
    """The plan of a dropped robot's remaining area (its part ``polygon`` less ``swept``) for ``survivors``
    robots; None when nothing is worth re-planning or the plan is over the limits (limits.py). Pure: it runs
    on the planner pool and changes nothing."""
    part = _polygon_of(polygon).intersection(region)
    if keep_clear:
        reach = min_sep + width / 2 + KEEP_CLEAR_MARGIN_M
        part = part.difference(unary_union([Point(p).buffer(reach) for p in keep_clear]))
    if part.is_empty or not survivors:
        return None
    left = part.difference(swept)
    w = width
    left = left.buffer(-w / 8).buffer(w / 8).intersection(part)  # hairline slivers along swept edges are not work
    if left.is_empty or left.area < max(REPLAN_MIN_SHARE * part.area, w * w):
        return None
    try:
        check_coverage(
            estimate_coverage(left, survivors, w * (1 - overlap), region_corners(left)), w, overlap, survivors
        )
        return plan_coverage(left, survivors, w, overlap, min_sep)
    except PlanError:
        return None


def hand_over(dropped: MissionRobot, survivors: list[MissionRobot], plan: CoveragePlan | None) -> int:
    """Append each survivor's new part (on the event loop: the mission's robots change only there)."""
    if plan is None:
        return 0
    for robot, sub in zip(survivors, plan.parts, strict=True):
        extra = [[round(x, 4), round(y, 4)] for x, y in sub.path]
        if not extra:
            continue
        robot.path = robot.path + extra
        robot.breaks = sorted({*robot.breaks, len(robot.path)})
        # its part grows by the new one: should it drop out in turn, what it had not swept of either goes on
        robot.polygon = rings(unary_union([_polygon_of(robot.polygon), sub.polygon]))
        robot.area_m2 = round(robot.area_m2 + sub.area_m2, 4)
        if robot.status == "done":
            robot.status = "pending"
    dropped.polygon = []
    return sum(1 for p in plan.parts if p.path)


def geometry_of(rings_: list[list[list[float]]]) -> BaseGeometry:
    return _polygon_of(rings_)


def geojson(geom: BaseGeometry) -> dict[str, Any]:
    return dict(geom.__geo_interface__) if not geom.is_empty else {"type": "GeometryCollection", "geometries": []}


__all__ = [
    "Coverage",
    "MissionRobot",
    "built_coverage",
    "geojson",
    "geometry_of",
    "hand_over",
    "plan_takeover",
    "replan",
    "rings",
    "robots_from_plan",
    "takeover_of",
]
