"""The geofence over every motion: the site the robot knows, the checks of a goal and of a motion's
stopping point against its fence, and the ``geofence`` stream's events.

Apart from the runner because the fence meets more than goals: a ``drive`` command, the seed's held drive
commands and an idle robot drifting with the water are checked here too. The geometry itself (safe and
motion regions) is :mod:`robot_agent.motion.geofence`'s; this is what the robot does with it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

from fleet_protocol import GEOFENCE_STREAM, MotionFailure
from robot_agent.motion import limits
from robot_agent.motion.controller import Estimate
from robot_agent.motion.geofence import SiteState
from robot_agent.motion.goal import geofence_report
from robot_agent.motion.kinematics import Kinematics, WheelCommand

log = logging.getLogger(__name__)


class FenceGuard:
    def __init__(self, *, kinematics: Kinematics, emit: Callable[[str, dict[str, Any]], object]) -> None:
        self.kin = kinematics
        self._emit = emit
        self.site = SiteState.unknown()
        self._outside_reported = False

    def goal_problem(self, points: list[tuple[float, float]], closed: bool, est: Estimate) -> str | None:
        """Why a goal through ``points`` (a loop when ``closed``) may not start from ``est``; None if it may."""
        fence = self.site.fence
        if fence is None:
            return None
        why = fence.path_problem(points, closed) if len(points) > 1 or closed else fence.point_problem(*points[0])
        if why is None:
            why = fence.leg_problem((est.x, est.y), points[0])
        return None if why is None else f"{MotionFailure.GEOFENCE}: {why} ({self.site.describe()})"

    def motion_problem(self, est: Estimate, wheels: WheelCommand) -> str | None:
        """Why these set-points must stop: the stopping point, current included, would leave the fence."""
        fence = self.site.fence
        if fence is None or wheels.linear == 0.0:
            return None
        vx = wheels.linear * math.cos(est.yaw) + est.cx
        vy = wheels.linear * math.sin(est.yaw) + est.cy
        return fence.motion_problem(est.x, est.y, vx, vy, self.kin.stop_time_s + limits.LOOKAHEAD_EXTRA_S)

    def drive_problem(self, est: Estimate, left: float, right: float) -> str | None:
        """:meth:`motion_problem` for a drive command's wheel speeds."""
        linear, angular = self.kin.body(left, right)
        return self.motion_problem(est, WheelCommand(left, right, linear, angular, False))

    def event(self, event: str, command_id: str | None, est: Estimate, reason: str) -> None:
        """A ``geofence`` message: a motion ``stopped`` or ``refused``, an idle robot ``outside`` or ``inside``."""
        if event in ("stopped", "refused"):
            log.warning("geofence %s %s at (%.3f, %.3f): %s", event, command_id or "", est.x, est.y, reason)
        self._emit(GEOFENCE_STREAM, geofence_report(event, command_id, est, reason, self.site.version))

    def watch_idle(self, est: Estimate) -> None:
        """An idle robot is not stopped (it is not moving itself), but its drifting out and back is reported."""
        fence = self.site.fence
        if fence is None:
            return
        outside = fence.outside_safe(est.x, est.y)
        if outside != self._outside_reported:
            self._outside_reported = outside
            event = "outside" if outside else "inside"
            if outside:
                log.warning("idle robot drifted out of the safe region at (%.3f, %.3f)", est.x, est.y)
            self.event(event, None, est, "idle: drifting with the water" if outside else "")
