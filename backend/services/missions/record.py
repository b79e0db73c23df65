"""A mission's record: the in-memory mission, its database row, its API shape and its summary in the list
(planning.py makes a new one's plan; service.py runs it)."""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field
from typing import Any

from backend.schemas.missions import (
    MissionPart,
    MissionPublic,
    MissionRobotProgress,
    MissionSummary,
)
from backend.services.missions.state import DEFAULT_SPEED_MPS, Coverage, MissionRobot


@dataclass
class Mission:
    id: str
    name: str
    type: str
    state: str
    robot_ids: list[str]
    params: dict[str, Any]
    created_by: str
    created_at: float
    updated_at: float
    plan: dict[str, Any]
    robots: list[MissionRobot]
    coverage: Coverage
    reason: str = ""
    started_at: float | None = None
    ended_at: float | None = None
    run_s: float = 0.0
    running_since: float | None = None
    saved_at: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    #: the server replica that runs it (its row lease); None: none has yet
    owner: str | None = None
    #: pause or abort asked through another replica, not applied yet by the owner
    requested: dict[str, Any] | None = None
    #: the run it opened when it started (recording its robots until it ends); None: none
    run_id: int | None = None
    #: the latest rehearsal's prediction (services/rehearsal; without its tracks): the run it starts records it
    rehearsal: dict[str, Any] | None = None

    def robot(self, robot_id: str) -> MissionRobot | None:
        return next((r for r in self.robots if r.robot_id == robot_id), None)

    def elapsed(self, now: float) -> float:
        return self.run_s + (now - self.running_since if self.running_since is not None else 0.0)


def coverage_of(plan: dict[str, Any], params: dict[str, Any]) -> Coverage:
    """The plan's coverage with its grid (on the planner pool: up to a few hundred ms for a large area)."""
    return Coverage(plan.get("workable", []), plan.get("holes", []), float(params.get("sweep_width_m", 0.2)))


def stored_coverage(plan: dict[str, Any], params: dict[str, Any], progress: dict[str, Any]) -> Coverage:
    """A row's coverage: the figures its owner stored, no geometry (cheap: a row is read on the event loop;
    state.built_coverage makes its grid on the planner pool when it is needed)."""
    stored = (float(progress.get("covered_fraction") or 0.0), dict(progress.get("swept_m2") or {}))
    return Coverage(plan.get("workable", []), plan.get("holes", []), float(params.get("sweep_width_m", 0.2)), stored)


def mission_row(m: Mission, full: bool = False) -> dict[str, Any]:
    row: dict[str, Any] = {
        "state": m.state,
        "reason": m.reason,
        "updated_at": m.updated_at,
        "started_at": m.started_at,
        "ended_at": m.ended_at,
        "run_s": m.elapsed(time.time()) if m.state == "running" else m.run_s,
        "plan": m.plan,
        "progress": {
            "run_id": m.run_id,
            "robots": [r.to_json() for r in m.robots],
            "covered_fraction": m.coverage.fraction,
            "swept_m2": m.coverage.per_robot,
            "rehearsal": m.rehearsal,
        },
    }
    if full:
        row.update(
            id=m.id,
            name=m.name,
            type=m.type,
            robots=m.robot_ids,
            params=m.params,
            created_by=m.created_by,
            created_at=m.created_at,
        )
    return row


def mission_public(m: Mission) -> MissionPublic:
    now = time.time()
    speed = float(m.params.get("speed") or DEFAULT_SPEED_MPS)
    left = max((r.remaining_m() for r in m.robots if r.active), default=0.0)
    return MissionPublic(
        id=m.id,
        name=m.name,
        type=m.type,
        state=m.state,  # type: ignore[arg-type]
        reason=m.reason,
        robots=m.robot_ids,
        params=m.params,
        created_by=m.created_by,
        created_at=m.created_at,
        updated_at=m.updated_at,
        started_at=m.started_at,
        ended_at=m.ended_at,
        elapsed_s=round(m.elapsed(now), 2),
        eta_s=round(left / speed, 1) if m.state in ("draft", "running", "paused") else None,
        covered_fraction=round(m.coverage.fraction, 4),
        workable_area_m2=float(m.plan.get("workable_area_m2", 0.0)),
        band_m=float(m.plan.get("band_m", 0.0)),
        replica=m.owner,
        requested=(m.requested or {}).get("action"),
        run_id=m.run_id,
        rehearsal=m.rehearsal,
        parts=[
            MissionPart(
                robot_id=r.robot_id,
                polygon=r.polygon,
                path=r.path,
                head_end=r.head_pass,
                tail_start=r.gate_at if r.gate_at is not None else len(r.path),
                area_m2=r.area_m2,
                length_m=round(_length(r.path), 3),
            )
            for r in m.robots
        ],
        progress=[
            MissionRobotProgress(
                robot_id=r.robot_id,
                status=r.status,
                reason=r.reason,
                waypoint_index=max(r.index, r.reached),
                waypoint_count=len(r.path),
                fraction=round(min(1.0, max(r.index, r.reached) / max(1, len(r.path))), 4),
                swept_m2=round(m.coverage.per_robot.get(r.robot_id, 0.0), 4),
            )
            for r in m.robots
        ],
    )


def mission_summaries(missions: list[Mission]) -> list[MissionSummary]:
    return [
        MissionSummary(
            id=m.id,
            name=m.name,
            type=m.type,
            state=m.state,  # type: ignore[arg-type]
            reason=m.reason,
            robots=m.robot_ids,
            created_at=m.created_at,
            covered_fraction=round(m.coverage.fraction, 4),
            started_at=m.started_at,
            ended_at=m.ended_at,
            run_id=m.run_id,
        )
        for m in sorted(missions, key=lambda m: m.created_at, reverse=True)
    ]


def _length(path: list[list[float]]) -> float:
    return sum(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in itertools.pairwise(path))
