"""A goal the motion runner is following, how a ``goto`` or ``follow_path`` command becomes one (its
:class:`Plan`: pure, from the arguments and the pose), and the messages that report goals, drives and the
geofence."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from fleet_protocol import FollowPathArgs, GotoArgs
from robot_agent.motion import limits
from robot_agent.motion.controller import Estimate, GotoController, PathFollower, Step
from robot_agent.motion.kinematics import STOPPED, Kinematics, WheelCommand


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


@dataclass(frozen=True, slots=True)
class Plan:
    """What a command asks for: its controller, its reports' ``goal`` and its time limit (None: none)."""

    mode: str
    controller: GotoController | PathFollower
    goal: dict[str, Any]
    timeout: float | None


def plan_goto(args: GotoArgs, est: Estimate, kin: Kinematics) -> Plan:
    """Without a ``timeout_s``: 15 s plus three times the straight run at the goal's speed."""
    speed = args.max_speed or limits.DEFAULT_GOAL_SPEED_MPS
    ctl = GotoController(args.x, args.y, args.yaw, args.tolerance_m, speed, kin)
    dist = math.hypot(args.x - est.x, args.y - est.y)
    timeout = args.timeout_s or 15.0 + 3.0 * dist / min(speed, kin.max_linear_mps)
    goal = {"x": args.x, "y": args.y, "yaw": args.yaw, "tolerance_m": args.tolerance_m}
    return Plan("goto", ctl, goal, timeout)


def path_points(args: FollowPathArgs) -> list[tuple[float, float]]:
    return [(p[0], p[1]) for p in args.waypoints]


def plan_path(args: FollowPathArgs, est: Estimate, kin: Kinematics) -> Plan:
    """Without a ``timeout_s``: 15 s plus three times the path's run plus 2 s a waypoint; a loop has none."""
    points = path_points(args)
    speed = args.max_speed or limits.DEFAULT_GOAL_SPEED_MPS
    ctl = PathFollower((est.x, est.y), points, args.tolerance_m, speed, args.loop, kin)
    length = ctl.remaining(est)
    timeout = args.timeout_s
    if timeout is None and not args.loop:
        timeout = 15.0 + 3.0 * length / min(speed, kin.max_linear_mps) + 2.0 * len(points)
    goal = {"waypoints": len(points), "tolerance_m": args.tolerance_m, "loop": args.loop, "last": list(points[-1])}
    return Plan("follow_path", ctl, goal, timeout)


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
