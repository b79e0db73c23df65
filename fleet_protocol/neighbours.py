"""Robots never collide (docs/safety.md): the fleet's poses, which every robot hears, and the avoidance stream,
which says when and by how much a robot's safety filter changed what it was told.

- ``{prefix}/poses`` (:class:`FleetPoses`, QoS 0, about 10 Hz, written by servers only, read by every robot):
  each robot the server heard a position fix from, as a compact row ``[id, x, y, yaw, vx, vy, age_s,
  filtered]``. ``age_s`` is how old that fix was when the message was sent (the robot adds the time since it
  heard the message); ``filtered`` is false for a robot that does not run the filter (the old framework), which
  every other robot then keeps clear of alone. Each server replica publishes the robots it heard; a robot keeps
  the newest fix of each.
- The ``avoidance`` telemetry stream (:class:`AvoidanceData`): an intervention, while it lasts, at most 10 a
  second, and its end.
- The site message's ``avoidance`` (:class:`AvoidanceSettings`): the filter's settings, versioned with the
  site. A site without it (an older server, which publishes no poses) leaves robots without the filter.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from fleet_protocol.codec import _load_json, _validate
from fleet_protocol.core import _finite, _Wire, is_valid_robot_id

#: The fleet's poses: period, QoS (a late pose is worthless: never queued), at most this many robots a message
POSES_PERIOD_S = 0.1
QOS_POSES = 0
MAX_POSES = 256
#: A neighbour whose fix is older than this is stale: the robot creeps near it. A robot that heard no poses
#: message for this long knows nothing of its neighbours: it refuses new goals and creeps.
POSE_STALE_S = 0.5
#: The avoidance telemetry stream
AVOIDANCE_STREAM = "avoidance"
#: A robot's body radius (the snail's shell): a goal inside another robot's body is refused
BODY_RADIUS_M = 0.1

#: one robot's row: id, x, y (m), yaw (rad or null), vx, vy (m/s), the fix's age (s), runs the filter
PoseRow = tuple[str, float, float, float | None, float, float, float, bool]


class FleetPoses(_Wire):
    """``{prefix}/poses``: the latest fix of every robot a server heard (see the module's docstring)."""

    server_id: str = Field(min_length=1, max_length=64)
    ts: float
    seq: int = Field(ge=0)
    robots: list[PoseRow] = Field(default_factory=list, max_length=MAX_POSES)

    _ts = field_validator("ts")(_finite)

    @field_validator("robots")
    @classmethod
    def _rows_finite(cls, rows: list[PoseRow]) -> list[PoseRow]:
        for row in rows:
            robot_id, x, y, yaw, vx, vy, age, _ = row
            if not is_valid_robot_id(robot_id):
                raise ValueError(f"bad robot id {robot_id[:80]!r}")
            for v in (x, y, vx, vy, age) if yaw is None else (x, y, yaw, vx, vy, age):
                _finite(v)
            if age < 0:
                raise ValueError("a fix's age is never negative")
        return rows


class AvoidanceSettings(BaseModel):
    """The safety filter's settings for a site (``SiteMessage.avoidance``). The distance kept between two
    robots' centres is the site's ``min_separation_m`` plus ``margin_m`` plus what grows with speed, with the
    age of the neighbour's fix and with the measured drift (docs/autonomy.md)."""

    model_config = ConfigDict(extra="ignore")

    enabled: bool = True
    margin_m: float = Field(default=0.03, ge=0.0, le=2.0)
    #: the speed a robot keeps near a neighbour whose pose is stale, or when it hears no poses at all
    creep_mps: float = Field(default=0.03, ge=0.0, le=0.5)

    _margin = field_validator("margin_m", "creep_mps")(_finite)


class AvoidanceData(BaseModel):
    """``avoidance`` stream: the filter changed a command (``active``, at most 10 a second while it lasts)
    or stopped changing it (``cleared``). Speeds are the body's, m/s and rad/s, before and after."""

    model_config = ConfigDict(extra="ignore")

    event: Literal["active", "cleared"]
    #: why: a neighbour's barrier, a neighbour whose pose is stale, no poses heard at all, giving way in a
    #: jam (robot_agent/motion/give_way.py), or a parked robot keeping clear of a neighbour (or of the water)
    cause: Literal["barrier", "stale", "no_poses", "give_way", "keep_clear", ""] = ""
    neighbour: str | None = None
    distance_m: float | None = None
    safety_m: float | None = None
    linear: float = 0.0
    angular: float = 0.0
    filtered_linear: float = 0.0
    filtered_angular: float = 0.0
    #: since when this intervention lasts (seconds; 0 on its first message)
    duration_s: float = 0.0


def decode_poses(payload: bytes) -> FleetPoses:
    return _validate(FleetPoses, _load_json(payload), "bad_poses")


__all__ = [
    "AVOIDANCE_STREAM",
    "BODY_RADIUS_M",
    "MAX_POSES",
    "POSES_PERIOD_S",
    "POSE_STALE_S",
    "QOS_POSES",
    "AvoidanceData",
    "AvoidanceSettings",
    "FleetPoses",
    "PoseRow",
    "decode_poses",
]
