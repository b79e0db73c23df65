"""Missions (``/api/missions``): what a client sends to create one and what it reads back."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from backend.schemas.separation import SeparationStats
from fleet_protocol import MAX_COORDINATE_M, MAX_PATH_WAYPOINTS, MAX_POLYGON_POINTS

MissionState = Literal["draft", "running", "paused", "completed", "aborted", "failed"]
RobotId = Annotated[str, Field(min_length=1, max_length=64)]
MAX_MISSION_ROBOTS = 20
# Numbers are JSON numbers (never booleans), finite. Plain pydantic constraints, so that the OpenAPI states
# the bounds (fleet_protocol's FiniteNumber validates after the fact and its bounds do not reach the schema).
Coordinate = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_COORDINATE_M, le=MAX_COORDINATE_M)]
Point = Annotated[list[Coordinate], Field(min_length=2, max_length=2)]
Polygon = Annotated[list[Point], Field(min_length=3, max_length=MAX_POLYGON_POINTS)]
Speed = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0.0, le=1.0)]


def _unique(robots: list[str]) -> list[str]:
    if len(set(robots)) != len(robots):
        raise ValueError("each robot may be named once")
    return robots


class CoverageParams(BaseModel):
    """Sweep ``area`` (default: the site boundary), minus the site's keep-outs, with every robot."""

    model_config = ConfigDict(extra="forbid")

    area: Polygon | None = Field(default=None, description="[x, y] corners in metres; none: the whole site")
    sweep_width_m: float = Field(default=0.2, strict=True, allow_inf_nan=False, gt=0.0, le=2.0)
    overlap: float = Field(
        default=0.0, strict=True, allow_inf_nan=False, ge=0.0, lt=0.9, description="fraction of the width lanes share"
    )
    speed: Speed | None = Field(default=None, description="m/s; none: the robots' default")


class WaypointsParams(BaseModel):
    """One path per robot, all started at the same moment."""

    model_config = ConfigDict(extra="forbid")

    paths: dict[RobotId, Annotated[list[Point], Field(min_length=1, max_length=MAX_PATH_WAYPOINTS)]] = Field(
        min_length=1, max_length=MAX_MISSION_ROBOTS
    )
    speed: Speed | None = Field(default=None, description="m/s; none: the robots' default")


#: A slot's offset from the leader, metres in its frame: [forward, left].
SlotOffset = Annotated[
    list[Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-3.0, le=3.0)]], Field(min_length=2, max_length=2)
]


class FormationParams(BaseModel):
    """The leader follows ``path`` by itself; each other robot holds its slot (the formation law of
    fleet_common/formation.py, run by the server on the robots' live positions)."""

    model_config = ConfigDict(extra="forbid")

    leader: RobotId = Field(description="the robot that follows the path; one of the mission's robots")
    path: list[Point] = Field(min_length=2, max_length=MAX_PATH_WAYPOINTS, description="the leader's [x, y] path")
    loop: bool = Field(default=True, description="go round the path until aborted (or duration_s)")
    slots: dict[RobotId, SlotOffset] = Field(
        min_length=1,
        max_length=MAX_MISSION_ROBOTS - 1,
        description="each follower's slot, [forward, left] metres in the leader's frame",
    )
    speed: float = Field(
        default=0.08,
        strict=True,
        allow_inf_nan=False,
        gt=0.0,
        le=0.15,
        description="the leader's speed, m/s: below the followers' (an outer slot moves faster than the leader)",
    )
    duration_s: float | None = Field(
        default=None,
        strict=True,
        allow_inf_nan=False,
        gt=0.0,
        le=86400.0,
        description="the mission completes after this long running; none: when the path ends (or an abort)",
    )


class _MissionCreateBase(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str = Field(default="", max_length=200)
    robots: list[RobotId] = Field(min_length=1, max_length=MAX_MISSION_ROBOTS, json_schema_extra={"uniqueItems": True})

    @field_validator("robots")
    @classmethod
    def _robots_unique(cls, v: list[str]) -> list[str]:
        return _unique(v)


class CoverageMissionCreate(_MissionCreateBase):
    type: Literal["coverage"]
    params: CoverageParams = Field(default_factory=CoverageParams)


class WaypointsMissionCreate(_MissionCreateBase):
    type: Literal["waypoints"]
    params: WaypointsParams


class FormationMissionCreate(_MissionCreateBase):
    type: Literal["formation"]
    params: FormationParams


MissionCreate = Annotated[
    CoverageMissionCreate | WaypointsMissionCreate | FormationMissionCreate, Field(discriminator="type")
]


class MissionAction(BaseModel):
    model_config = ConfigDict(extra="forbid")

    reason: str = Field(default="", max_length=500)


class MissionResume(MissionAction):
    rejoin: list[RobotId] = Field(default_factory=list, max_length=MAX_MISSION_ROBOTS, description="dropped robots")


class MissionPart(BaseModel):
    """A robot's share of the plan: its polygon (coverage) and its path."""

    robot_id: str
    polygon: list[list[list[float]]] = Field(default_factory=list, description="rings of [x, y] (may be empty)")
    path: list[list[float]]
    head_end: int = 0
    tail_start: int = 0
    area_m2: float = 0.0
    length_m: float = 0.0


class MissionRobotProgress(BaseModel):
    robot_id: str
    #: pending, moving, waiting (for separation), done, dropped (offline/failed: work re-planned), paused
    status: str
    reason: str = ""
    waypoint_index: int = 0
    waypoint_count: int = 0
    fraction: float = Field(description="share of its planned path travelled, 0..1")
    swept_m2: float = Field(description="area of the workable region this robot's track swept")


class MissionTransition(BaseModel):
    ts: float
    from_state: str
    to_state: str
    actor: str
    reason: str = ""


class MissionEvent(BaseModel):
    ts: float
    kind: str
    robot_id: str | None = None
    detail: dict[str, Any] = Field(default_factory=dict)


class MissionPublic(BaseModel):
    id: str
    name: str
    type: str
    state: MissionState
    reason: str = ""
    robots: list[str]
    params: dict[str, Any]
    created_by: str
    created_at: float
    updated_at: float
    started_at: float | None = None
    ended_at: float | None = None
    elapsed_s: float = Field(description="time spent running (pauses excluded)")
    eta_s: float | None = Field(default=None, description="estimated running time left; none: not known yet")
    covered_fraction: float = Field(description="share of the workable area swept by the robots' actual tracks")
    workable_area_m2: float = 0.0
    band_m: float = Field(default=0.0, description="band along the boundary and keep-outs left out of the area")
    replica: str | None = Field(default=None, description="the server replica that runs it (ran it last)")
    requested: str | None = Field(
        default=None, description="pause or abort asked through another replica, for the one running it to apply"
    )
    run_id: int | None = Field(default=None, description="the run it opened when it started (GET /api/runs/{id})")
    rehearsal: dict[str, Any] | None = Field(
        default=None,
        description="the latest rehearsal's prediction (POST /api/missions/{id}/rehearsal), without its tracks: the "
        "run the mission starts records it (docs/missions.md, Rehearsal)",
    )
    parts: list[MissionPart] = Field(default_factory=list)
    progress: list[MissionRobotProgress] = Field(default_factory=list)
    transitions: list[MissionTransition] = Field(default_factory=list)
    events: list[MissionEvent] = Field(default_factory=list)
    separation: SeparationStats | None = Field(
        default=None,
        description="an ended mission's report (GET /api/missions/{id}): how close its robots came, violations "
        "and contacts, and their safety filters' interventions (docs/runs.md, Separation)",
    )


class MissionSummary(BaseModel):
    id: str
    name: str
    type: str
    state: MissionState
    reason: str = ""
    robots: list[str]
    created_at: float
    covered_fraction: float
    started_at: float | None = None
    ended_at: float | None = None
    run_id: int | None = Field(default=None, description="the run it opened when it started (GET /api/runs/{id})")
