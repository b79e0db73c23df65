"""Experiment runs (issue 19): start, stop, annotate, find, and the summary of what happened in one."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field

from backend.schemas.separation import SeparationStats
from fleet_protocol import StrictNumber

#: what agents accept as a robot id (fleet-agent --robot-id)
RobotId = Annotated[str, Field(pattern=r"^[A-Za-z0-9_-]{1,64}$")]
#: "|" separates tags in the search index (store/runs.py)
Tag = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[^|]+$")]


# Lengths keep the largest valid body under FLEET_MAX_BODY_BYTES (64 KiB) even with every character
# escaped as JSON \uXXXX pairs: a valid request is never refused as too large.


class RunCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str = Field(min_length=1, max_length=200)
    notes: str = Field(default="", max_length=2000)
    tags: list[Tag] = Field(default_factory=list, max_length=16)
    #: the robots recorded; none: every robot online now
    robots: list[RobotId] | None = Field(default=None, min_length=1, max_length=100)
    #: camera frames kept per second and robot (0: none; at most the camera's own rate is kept)
    frame_rate: StrictNumber = Field(default=5.0, ge=0, le=60)


class RunUpdate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str | None = Field(default=None, min_length=1, max_length=200)
    notes: str | None = Field(default=None, max_length=2000)
    tags: list[Tag] | None = Field(default=None, max_length=16)


class RunPublic(BaseModel):
    id: int
    name: str
    notes: str
    tags: list[str]
    operator: str
    robots: list[str]
    started_at: float
    #: null while the run is recording
    ended_at: float | None
    running: bool
    site_version: int
    #: robot id -> agent version, protocol version, capabilities, sensors (from its status at the start)
    agents: dict[str, Any]
    frame_rate: float
    frames: int
    frame_bytes: int
    #: frame recording stopped because the frame store's quota would be exceeded (telemetry went on)
    frames_stopped: bool
    frames_stopped_reason: str
    #: the mission that opened the run (GET /api/missions/{id}); null for a run started by hand
    mission_id: str | None = None


class MarkerCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    text: str = Field(min_length=1, max_length=2000)
    #: when it happened (server clock, unix seconds); none: now
    ts: StrictNumber | None = Field(default=None)
    robot_id: RobotId | None = None


class MarkerPublic(BaseModel):
    id: int
    run_id: int
    ts: float
    text: str
    robot_id: str | None
    author: str
    created_at: float


class StreamCount(BaseModel):
    robot_id: str
    stream: str
    count: int
    first_ts: float | None
    last_ts: float | None


class StreamGap(BaseModel):
    """Seq numbers missing from what is stored of one stream (``lo``..``hi`` inclusive, after ``ts``)."""

    robot_id: str
    stream: str
    lo: int
    hi: int
    ts: float


class RunSummary(BaseModel):
    duration_s: float
    robots: list[str]
    messages: list[StreamCount]
    messages_total: int
    #: metres travelled per robot, from its stored positions
    distance_m: dict[str, float]
    commands: int
    commands_by_status: dict[str, int]
    estops: int
    alarms: int
    alarm_kinds: dict[str, int]
    gaps: list[StreamGap]
    #: seq numbers missing over every stream
    gaps_missing: int
    #: more gaps than listed
    gaps_truncated: bool
    #: how close the robots came and the safety filters' interventions (GET /api/runs/{id} only)
    separation: SeparationStats | None = None


class RunDetail(RunPublic):
    summary: RunSummary
    markers: list[MarkerPublic]


class RunFrame(BaseModel):
    """A stored camera frame of a run and the AprilTag detections of that frame (the replay's camera)."""

    robot_id: str
    #: the robot's time stamp of the frame (epoch s)
    ts: float
    frame_seq: int
    #: the ``apriltag`` message of the same ``frame_seq`` (image_size, camera, detections), null when none
    detections: dict[str, Any] | None
    #: the JPEG, base64 (``format=jpeg`` answers the bytes instead)
    jpeg_base64: str


class RunFrameTimes(BaseModel):
    """When a robot's stored frames of a run were taken: the replay finds the frame of a moment locally."""

    robot_id: str
    #: [ts, frame_seq] of each stored frame, in time order
    frames: list[tuple[float, int]]
