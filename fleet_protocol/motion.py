"""Closed-loop motion and the site: command arguments, the ``motion`` stream and the retained site model.

Additions to protocol version 1 (older agents do not announce these commands, older servers ignore the
new stream and topic). The argument models are what the robot validates a command with and what the
server reuses to answer 422 before anything is sent: every number is a JSON number (never a boolean),
finite and bounded.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator

from fleet_protocol.codec import _load_json, _validate
from fleet_protocol.core import DEFAULT_DRIVE_DURATION_S, MAX_DRIVE_DURATION_S, ProtocolError
from fleet_protocol.neighbours import AvoidanceSettings


def _finite_number(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError("must be a finite number")
    return v


#: A finite JSON number (never a boolean, never NaN or infinity).
FiniteNumber = Annotated[float, Field(strict=True), AfterValidator(_finite_number)]
#: Site coordinates are metres in the Lighthouse frame; a pool is a few metres, 1 km is absurd.
MAX_COORDINATE_M = 1000.0
Coordinate = Annotated[FiniteNumber, Field(ge=-MAX_COORDINATE_M, le=MAX_COORDINATE_M)]
#: A point ``[x, y]``.
Point = Annotated[list[Coordinate], Field(min_length=2, max_length=2)]

MAX_LINEAR_MPS = 5.0
MAX_ANGULAR_RPS = 20.0
MAX_PATH_WAYPOINTS = 500
MAX_GOAL_TIMEOUT_S = 3600.0
MAX_POLYGON_POINTS = 1000
MAX_KEEPOUTS = 100

MOTION_COMMANDS: tuple[str, ...] = ("drive", "goto", "follow_path")
#: Telemetry streams of the motion controller.
MOTION_STREAM = "motion"
GEOFENCE_STREAM = "geofence"


class VelocityDriveArgs(BaseModel):
    """``drive``: continuous velocity control (``cmd_vel``). Repeat at 10-20 Hz; ``duration_s`` is the deadman.
    The robot mixes it into wheel set-points within its kinematic limits and reports the clamped values."""

    model_config = ConfigDict(extra="forbid")

    linear: FiniteNumber = Field(ge=-MAX_LINEAR_MPS, le=MAX_LINEAR_MPS, description="m/s, + forward")
    angular: FiniteNumber = Field(
        default=0.0, ge=-MAX_ANGULAR_RPS, le=MAX_ANGULAR_RPS, description="rad/s, + counter-clockwise"
    )
    duration_s: FiniteNumber = Field(default=DEFAULT_DRIVE_DURATION_S, gt=0.0, le=MAX_DRIVE_DURATION_S)


class GotoArgs(BaseModel):
    """``goto``: drive to (x, y) [and turn to yaw] with the robot's own controller on its position stream."""

    model_config = ConfigDict(extra="forbid")

    x: Coordinate
    y: Coordinate
    yaw: FiniteNumber | None = Field(default=None, ge=-2 * math.pi, le=2 * math.pi)
    tolerance_m: FiniteNumber = Field(default=0.05, ge=0.01, le=5.0)
    max_speed: FiniteNumber | None = Field(default=None, gt=0.0, le=MAX_LINEAR_MPS, description="m/s")
    timeout_s: FiniteNumber | None = Field(default=None, gt=0.0, le=MAX_GOAL_TIMEOUT_S)
    supervisor: str | None = Field(
        default=None,
        min_length=1,
        max_length=64,
        description="the server replica whose heartbeat this goal needs (its server_id); none: any server's",
    )


class FollowPathArgs(BaseModel):
    """``follow_path``: follow the polyline through ``waypoints`` (1-500), optionally forever (``loop``)."""

    model_config = ConfigDict(extra="forbid")

    waypoints: list[Point] = Field(min_length=1, max_length=MAX_PATH_WAYPOINTS)
    tolerance_m: FiniteNumber = Field(default=0.05, ge=0.01, le=5.0)
    max_speed: FiniteNumber | None = Field(default=None, gt=0.0, le=MAX_LINEAR_MPS)
    loop: bool = Field(default=False, strict=True)
    timeout_s: FiniteNumber | None = Field(default=None, gt=0.0, le=MAX_GOAL_TIMEOUT_S)
    supervisor: str | None = Field(
        default=None,
        min_length=1,
        max_length=64,
        description="the server replica whose heartbeat this goal needs (its server_id); none: any server's",
    )

    @model_validator(mode="after")
    def _loop_has_a_length(self) -> FollowPathArgs:
        if self.loop and len({(p[0], p[1]) for p in self.waypoints}) < 2:
            raise ValueError("a loop needs at least two different waypoints")
        return self


MOTION_ARGS: dict[str, type[BaseModel]] = {
    "drive": VelocityDriveArgs,
    "goto": GotoArgs,
    "follow_path": FollowPathArgs,
}


class MotionFailure(StrEnum):
    """The first word of a ``failed`` ack's reason."""

    TIMEOUT = "timeout"
    NO_POSITION = "no_position"
    GEOFENCE = "geofence"
    STALLED = "stalled"
    UNSUPERVISED = "unsupervised"
    LINK_LOST = "link_lost"
    #: the safety filter held the robot back from its goal (another robot in the way) for 10 s
    BLOCKED = "blocked"


MotionMode = Literal["drive", "goto", "follow_path", "hold"]
MotionState = Literal["active", "done", "failed", "aborted", "stopped"]


class WheelSetpoint(BaseModel):
    """What the controller asked of the motors: fractions of full wheel speed and the body velocity."""

    model_config = ConfigDict(extra="ignore")

    left: float
    right: float
    linear: float
    angular: float


class MotionData(BaseModel):
    """``motion`` stream: one message per control step (at least 5 Hz while a goal is active) and one when it
    ends. ``setpoint`` all zeros means the controller stopped the motors."""

    model_config = ConfigDict(extra="ignore")

    command_id: str = Field(max_length=64)
    mode: MotionMode
    state: MotionState
    reason: str = Field(default="", max_length=500)
    goal: dict[str, Any] | None = None
    distance_m: float | None = None
    waypoint_index: int | None = None
    waypoint_count: int | None = None
    cross_track_m: float | None = None
    setpoint: WheelSetpoint
    #: The requested body velocity of a ``drive`` when the kinematic limits clamped it.
    requested: dict[str, float] | None = None
    clamped: bool = False
    drift_mps: list[float] | None = None
    site_version: int | None = None


class GeofenceEvent(BaseModel):
    """``geofence`` stream: a motion stopped or refused at the fence, or an idle robot drifting across it."""

    model_config = ConfigDict(extra="ignore")

    event: Literal["stopped", "refused", "outside", "inside"]
    command_id: str | None = None
    x: float
    y: float
    reason: str = Field(default="", max_length=500)
    site_version: int | None = None


# --------------------------------------------------------------------------------------------------
# The site: one model of the pool, published retained by the server on ``{prefix}/site``.
# --------------------------------------------------------------------------------------------------

Polygon = Annotated[list[Point], Field(min_length=3, max_length=MAX_POLYGON_POINTS)]


def _check_polygon(points: list[list[float]], what: str) -> None:
    from shapely.geometry import Polygon as ShapelyPolygon

    poly = ShapelyPolygon(points)
    if not poly.is_valid or poly.area <= 0:
        raise ValueError(f"{what} is not a simple polygon with an area (self-intersecting or degenerate)")


class SiteTag(BaseModel):
    """A wall AprilTag: id, printed size and pose (x, y, z metres; yaw radians: the way its face looks)."""

    model_config = ConfigDict(extra="forbid")

    id: int = Field(ge=0, le=100_000, strict=True)
    size_m: FiniteNumber = Field(gt=0.0, le=10.0)
    pose: dict[Literal["x", "y", "z", "yaw"], FiniteNumber]


class SiteBaseStation(BaseModel):
    model_config = ConfigDict(extra="forbid")

    id: int | str
    position: list[FiniteNumber] = Field(min_length=3, max_length=3)
    rotation: list[list[FiniteNumber]] = Field(min_length=3, max_length=3)


class Site(BaseModel):
    """The pool: boundary, keep-outs, the geofence margin and the robots' minimum separation, the Lighthouse
    base stations and the AprilTag map."""

    model_config = ConfigDict(extra="forbid")

    boundary: Polygon
    keepouts: list[Polygon] = Field(default_factory=list, max_length=MAX_KEEPOUTS)
    geofence_margin_m: FiniteNumber = Field(default=0.15, ge=0.0, le=10.0)
    min_separation_m: FiniteNumber = Field(default=0.3, ge=0.0, le=10.0)
    base_stations: list[SiteBaseStation] = Field(default_factory=list, max_length=16)
    tags: list[SiteTag] = Field(default_factory=list, max_length=1000)

    @field_validator("boundary")
    @classmethod
    def _boundary_simple(cls, v: list[list[float]]) -> list[list[float]]:
        _check_polygon(v, "boundary")
        return v

    @field_validator("keepouts")
    @classmethod
    def _keepouts_simple(cls, v: list[list[list[float]]]) -> list[list[list[float]]]:
        for i, poly in enumerate(v):
            _check_polygon(poly, f"keepout {i}")
        return v

    @model_validator(mode="after")
    def _unique_tags(self) -> Site:
        ids = [t.id for t in self.tags]
        if len(ids) != len(set(ids)):
            raise ValueError("tag ids must be unique")
        return self


class SiteMessage(BaseModel):
    """``{prefix}/site`` (retained, QoS 1, written by the server only). ``site: null`` is a published state:
    "no fence", as opposed to a robot that has not received the topic yet (it then refuses goals)."""

    model_config = ConfigDict(extra="ignore")

    version: int = Field(ge=0, strict=True)
    site: Site | None
    ts: float | None = None
    #: the safety filter's settings (fleet_protocol.neighbours); absent from older servers: no filter
    avoidance: AvoidanceSettings | None = None


QOS_SITE = 1


def default_pool_site() -> Site:
    """The simulator's 4 m x 4 m pool, centred on the origin."""
    return Site(boundary=[[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]])


def decode_site(payload: bytes) -> SiteMessage:
    """An empty payload (the retained topic cleared on the broker) is not a site: raises ``bad_site``."""
    if not payload:
        raise ProtocolError("bad_site", "empty payload")
    return _validate(SiteMessage, _load_json(payload), "bad_site")


__all__ = [
    "GEOFENCE_STREAM",
    "MAX_ANGULAR_RPS",
    "MAX_COORDINATE_M",
    "MAX_GOAL_TIMEOUT_S",
    "MAX_KEEPOUTS",
    "MAX_LINEAR_MPS",
    "MAX_PATH_WAYPOINTS",
    "MAX_POLYGON_POINTS",
    "MOTION_ARGS",
    "MOTION_COMMANDS",
    "MOTION_STREAM",
    "QOS_SITE",
    "Coordinate",
    "FiniteNumber",
    "FollowPathArgs",
    "GeofenceEvent",
    "GotoArgs",
    "MotionData",
    "MotionFailure",
    "MotionMode",
    "MotionState",
    "Point",
    "Polygon",
    "Site",
    "SiteBaseStation",
    "SiteMessage",
    "SiteTag",
    "VelocityDriveArgs",
    "WheelSetpoint",
    "decode_site",
    "default_pool_site",
]
