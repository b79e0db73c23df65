"""A goal the motion runner is following, and the messages that report goals, drives and the geofence."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from robot_agent.motion.controller import Estimate, GotoController, PathFollower, Step
from robot_agent.motion.kinematics import STOPPED, WheelCommand


@dataclass
class Goal:
    command_id: str
    mode: str  # goto | follow_path | hold
    controller: GotoController | PathFollower
    goal: dict[str, Any]
    deadline: float | None
    site_version: int | None
    started: float
    best: float = math.inf
    best_at: float = 0.0
    last_step: Step | None = None
    #: The waypoint being approached when ``best`` was set: reaching a new one is progress too (a loop's
    #: distance left grows again at each corner).
    best_waypoint: int | None = None
    wheels: WheelCommand = field(default=STOPPED)
    #: the server replica whose heartbeat the goal needs (None: any server's)
    supervisor: str | None = None


def _setpoint(w: WheelCommand) -> dict[str, float]:
    return {
        "left": round(w.left, 4),
        "right": round(w.right, 4),
        "linear": round(w.linear, 4),
        "angular": round(w.angular, 4),
    }


def goal_report(goal: Goal, state: str, reason: str, est: Estimate | None) -> dict[str, Any]:
    """``motion`` stream data for a goal (or a hold-off at the fence)."""
    step = goal.last_step
    count = goal.controller.waypoint_count if isinstance(goal.controller, PathFollower) else None
    return {
        "command_id": goal.command_id,
        "mode": goal.mode,
        "state": state,
        "reason": reason[:500],
        "goal": goal.goal,
        "distance_m": None if step is None else round(step.distance_m, 4),
        "waypoint_index": None if step is None else step.waypoint_index,
        "waypoint_count": count,
        "cross_track_m": None if step is None or step.cross_track_m is None else round(step.cross_track_m, 4),
        "setpoint": _setpoint(goal.wheels),
        "clamped": goal.wheels.clamped,
        "drift_mps": None if est is None else [round(est.cx, 4), round(est.cy, 4)],
        "site_version": goal.site_version,
    }


def drive_report(
    command_id: str, wheels: WheelCommand, linear: float, angular: float, site_version: int | None
) -> dict[str, Any]:
    """``motion`` stream data for a ``drive`` command: its wheel set-points and what was clamped."""
    return {
        "command_id": command_id,
        "mode": "drive",
        "state": "active",
        "reason": "",
        "setpoint": _setpoint(wheels),
        "requested": {"linear": linear, "angular": angular},
        "clamped": wheels.clamped,
        "site_version": site_version,
    }


def geofence_report(
    event: str, command_id: str | None, est: Estimate, reason: str, site_version: int | None
) -> dict[str, Any]:
    """``geofence`` stream data: a motion stopped or refused at the fence, an idle robot out or back in."""
    return {
        "event": event,
        "command_id": command_id,
        "x": round(est.x, 4),
        "y": round(est.y, 4),
        "reason": reason[:500],
        "site_version": site_version,
    }
