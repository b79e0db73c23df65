"""One mission's live state: each robot's path, legs and track, and the geometry of its progress.

A robot's path is sent as *legs* (``follow_path`` commands) that end at breakpoints: after its head (the
lanes near the previous robot's part, plus the step to its next lane) and before its tail (the lanes near
the next robot's part). The tail waits until the next robot has finished its head leg (its ``done`` ack):
the separation rule of backend/services/missions/coverage.py. Progress is measured from where the robots actually went:
their tracks (positions sampled while running), buffered by the sweep width.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from shapely.geometry import LineString, MultiPolygon, Point, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.ops import unary_union

from backend.services.missions.coverage import CoveragePlan, PlanError, plan_coverage

#: a track point is kept when the robot moved this far since the previous one
TRACK_STEP_M = 0.02
#: a waypoint counts as passed when the robot came this close to it (display, resume)
PASS_RADIUS_M = 0.12
#: remaining area smaller than this share of a part is not worth re-planning
REPLAN_MIN_SHARE = 0.01
DEFAULT_SPEED_MPS = 0.15
#: beyond the separation and half a sweep: how far a stopped robot may drift while others sweep near it
KEEP_CLEAR_MARGIN_M = 0.15
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
    """Swept area of the tracks over the workable region (cached per track lengths)."""

    def __init__(self, workable: list[list[list[float]]], holes: list[list[list[float]]], width_m: float) -> None:
        region = _polygon_of(workable)
        if holes:
            region = region.difference(unary_union([Polygon(h) for h in holes if len(h) >= 3]))
        self.region = region
        self.width = width_m
        self._key: tuple[int, ...] = ()
        self.fraction = 0.0
        self.per_robot: dict[str, float] = {}
        self.swept: BaseGeometry = Polygon()

    def strip(self, track: list[list[float]]) -> BaseGeometry:
        if not track:
            return Polygon()
        if len(track) == 1:
            return Point(track[0]).buffer(self.width / 2)
        return LineString(track).buffer(self.width / 2)

    def update(self, robots: list[MissionRobot]) -> None:
        key = tuple(len(r.track) for r in robots)
        if key == self._key or self.region.is_empty:
            return
        self._key = key
        strips = {r.robot_id: self.strip(r.track) for r in robots}
        self.swept = unary_union(list(strips.values())).intersection(self.region)
        self.fraction = float(self.swept.area / self.region.area)
        self.per_robot = {rid: float(s.intersection(self.region).area) for rid, s in strips.items()}


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
    survivors got work."""
    part = _polygon_of(dropped.polygon).intersection(coverage.region)
    if keep_clear:
        reach = min_sep + coverage.width / 2 + KEEP_CLEAR_MARGIN_M
        part = part.difference(unary_union([Point(p).buffer(reach) for p in keep_clear]))
    if part.is_empty or not survivors:
        return 0
    left = part.difference(coverage.swept)
    w = coverage.width
    left = left.buffer(-w / 8).buffer(w / 8).intersection(part)  # hairline slivers along swept edges are not work
    if left.is_empty or left.area < max(REPLAN_MIN_SHARE * part.area, w * w):
        return 0
    try:
        plan = plan_coverage(left, len(survivors), w, overlap, min_sep)
    except PlanError:
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


__all__ = ["Coverage", "MissionRobot", "geojson", "geometry_of", "replan", "rings", "robots_from_plan"]
