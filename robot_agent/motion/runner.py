"""The motion runner: goals (goto, follow_path) in a control loop on the robot's own position fixes, their
supervision, and the geofence over every motion (goals, ``drive``, the seed's held drive commands).

It runs on the agent's asyncio loop. A control step runs on each position fix (the sensor rate);
:meth:`MotionRunner.tick` (every 25 ms) ends a goal that lost its fix (0.3 s), its supervision (no server
heartbeat for 1 s; or, for a goal that names its ``supervisor``, none from that server replica: another replica's
beat does not keep it going), its time or its progress. The command handler tells the runner (``preempt``) when a
stop, the e-stop, a lost link, shutdown or another drive ends what it is doing; goals are then acked
``aborted`` (or ``failed: link_lost``) and the motors stopped.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from typing import Any

from fleet_protocol import (
    GEOFENCE_STREAM,
    HEARTBEAT_SILENCE_S,
    MOTION_STREAM,
    Ack,
    AckStatus,
    FollowPathArgs,
    GotoArgs,
    MotionFailure,
    ProtocolError,
    decode_heartbeat,
    decode_site,
    make_ack,
)
from robot_agent.motion import limits
from robot_agent.motion.controller import DriftObserver, Estimate, GotoController, PathFollower
from robot_agent.motion.geofence import SiteState
from robot_agent.motion.goal import Goal, drive_report, geofence_report, goal_report
from robot_agent.motion.kinematics import STOPPED, Kinematics, WheelCommand
from robot_agent.motors.base import MotorDriver
from robot_agent.util import RejectCounter

log = logging.getLogger(__name__)

#: server replicas whose last beat is remembered
MAX_SERVERS = 16


class MotionRunner:
    def __init__(
        self,
        *,
        kinematics: Kinematics,
        motors: MotorDriver,
        send_ack: Callable[[Ack], None],
        emit: Callable[[str, dict[str, Any]], object],
        end_drive: Callable[[str], None],
        driving: Callable[[], bool],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.kin = kinematics
        self.motors = motors
        self._send_ack = send_ack
        self._emit = emit
        self._end_drive = end_drive
        self._driving = driving
        self._clock = clock
        self.site = SiteState.unknown()
        self.observer = DriftObserver()
        self.rejects = RejectCounter(log)
        self.goal: Goal | None = None
        self.hold: Goal | None = None  # station keeping after the geofence stopped a held drive
        self.hold_until = 0.0
        self.drive_wheels: tuple[float, float] = (0.0, 0.0)  # set-points of the running drive command
        self.last_fix_at: float | None = None
        self.last_heartbeat_at: float | None = None
        self.heartbeat_server: str | None = None
        #: when each server replica last beat (a goal naming its supervisor needs that replica's beat)
        self.heartbeats: dict[str, float] = {}
        self._last_report = 0.0
        self._outside_reported = False
        self.geofence_stops = 0

    # -- inputs ------------------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        """A goal or a hold-off is moving the robot (the link watchdog watches while this is true)."""
        return self.goal is not None or self.hold is not None

    def on_heartbeat_payload(self, payload: bytes) -> None:
        try:
            hb = decode_heartbeat(payload)
        except ProtocolError as exc:
            self.rejects.reject(exc.reason, exc.detail)
            return
        self.last_heartbeat_at = self._clock()
        self.heartbeat_server = hb.server_id
        self.heartbeats[hb.server_id] = self.last_heartbeat_at
        if len(self.heartbeats) > MAX_SERVERS:  # ids of replicas long gone are forgotten, oldest first
            del self.heartbeats[min(self.heartbeats, key=self.heartbeats.__getitem__)]

    def on_site_payload(self, payload: bytes) -> None:
        try:
            msg = decode_site(payload)
        except ProtocolError as exc:
            self.rejects.reject(exc.reason, exc.detail)
            return
        self.site = SiteState.from_message(msg)
        log.info("site received: %s", self.site.describe())

    def supervised(self, server: str | None = None) -> bool:
        """A server beat within HEARTBEAT_SILENCE_S: any, or the replica ``server``."""
        hb = self.last_heartbeat_at if server is None else self.heartbeats.get(server)
        return hb is not None and self._clock() - hb <= HEARTBEAT_SILENCE_S

    def _silence(self, server: str | None) -> str:
        hb = self.last_heartbeat_at if server is None else self.heartbeats.get(server)
        silent = "ever" if hb is None else f"{self._clock() - hb:.2f} s"
        return f"no heartbeat from server {server} for {silent}" if server else f"no server heartbeat for {silent}"

    def estimate(self) -> Estimate | None:
        """The filtered pose, when the last fix is recent enough to act on."""
        if self.last_fix_at is None or self._clock() - self.last_fix_at > limits.FIX_SILENCE_S:
            return None
        return self.observer.est

    # -- starting goals ------------------------------------------------------------------------------
    def _refusal(
        self, points: list[tuple[float, float]], closed: bool = False, supervisor: str | None = None
    ) -> str | None:
        if not self.site.received:
            return "no site received yet: goals need the site (its geofence) first"
        if not self.supervised(supervisor):
            source = f"server {supervisor}" if supervisor else "server"
            return f"{MotionFailure.UNSUPERVISED}: no {source} heartbeat in the last {HEARTBEAT_SILENCE_S} s"
        est = self.estimate()
        if est is None:
            return f"{MotionFailure.NO_POSITION}: no position fix"
        fence = self.site.fence
        if fence is not None:
            why = fence.path_problem(points, closed) if len(points) > 1 or closed else fence.point_problem(*points[0])
            if why is None:
                why = fence.leg_problem((est.x, est.y), points[0])
            if why is not None:
                return f"{MotionFailure.GEOFENCE}: {why} ({self.site.describe()})"
        return None

    def start_goto(self, command_id: str, args: GotoArgs) -> None:
        why = self._refusal([(args.x, args.y)], supervisor=args.supervisor)
        if why is not None:
            self._ack(command_id, AckStatus.REJECTED, why)
            return
        est = self.estimate()
        assert est is not None
        speed = args.max_speed or limits.DEFAULT_GOAL_SPEED_MPS
        ctl = GotoController(args.x, args.y, args.yaw, args.tolerance_m, speed, self.kin)
        dist = math.hypot(args.x - est.x, args.y - est.y)
        timeout = args.timeout_s or 15.0 + 3.0 * dist / min(speed, self.kin.max_linear_mps)
        goal = {"x": args.x, "y": args.y, "yaw": args.yaw, "tolerance_m": args.tolerance_m}
        self._begin(command_id, "goto", ctl, goal, timeout, args.supervisor)

    def start_path(self, command_id: str, args: FollowPathArgs) -> None:
        points = [(p[0], p[1]) for p in args.waypoints]
        why = self._refusal(points, closed=args.loop, supervisor=args.supervisor)
        if why is not None:
            self._ack(command_id, AckStatus.REJECTED, why)
            return
        est = self.estimate()
        assert est is not None
        speed = args.max_speed or limits.DEFAULT_GOAL_SPEED_MPS
        ctl = PathFollower((est.x, est.y), points, args.tolerance_m, speed, args.loop, self.kin)
        length = ctl.remaining(est)
        timeout = args.timeout_s
        if timeout is None and not args.loop:
            timeout = 15.0 + 3.0 * length / min(speed, self.kin.max_linear_mps) + 2.0 * len(points)
        goal = {"waypoints": len(points), "tolerance_m": args.tolerance_m, "loop": args.loop, "last": list(points[-1])}
        self._begin(command_id, "follow_path", ctl, goal, timeout, args.supervisor)

    def _begin(
        self,
        command_id: str,
        mode: str,
        ctl: GotoController | PathFollower,
        goal: dict[str, Any],
        timeout: float | None,
        supervisor: str | None = None,
    ) -> None:
        self._end_drive("superseded by " + mode)  # ends a running drive; preempt() aborts a running goal
        self._end_goal_if_any("superseded by " + mode)
        now = self._clock()
        self.goal = Goal(
            command_id,
            mode,
            ctl,
            goal,
            None if timeout is None else now + timeout,
            self.site.version,
            now,
            best_at=now,
            supervisor=supervisor,
        )
        self._ack(command_id, AckStatus.ACCEPTED, f"checked against {self.site.describe()}")
        log.info("%s %s started (%s)", mode, command_id, goal)

    # -- ending --------------------------------------------------------------------------------------
    def preempt(self, reason: str) -> None:
        """Something else took the motors (a stop, e-stop, lost link, shutdown, another drive)."""
        self.hold = None
        self._end_goal_if_any(reason)

    def _end_goal_if_any(self, reason: str) -> None:
        if self.goal is None:
            return
        if reason.startswith("link"):
            self._finish(AckStatus.FAILED, f"{MotionFailure.LINK_LOST}: {reason}")
        else:
            self._finish(AckStatus.ABORTED, reason)

    def _finish(self, status: AckStatus, reason: str) -> None:
        goal, self.goal = self.goal, None
        if goal is None:
            return
        self._stop_motors()
        self.observer.commanded(0.0, 0.0)
        goal.wheels = STOPPED
        state = {AckStatus.DONE: "done", AckStatus.FAILED: "failed"}.get(status, "aborted")
        self._report(goal, state, reason, force=True)
        self._ack(goal.command_id, status, reason)
        log.info("%s %s %s: %s", goal.mode, goal.command_id, status.value, reason)

    def fail(self, failure: MotionFailure, detail: str) -> None:
        self._finish(AckStatus.FAILED, f"{failure}: {detail}")

    # -- the control loop ----------------------------------------------------------------------------
    def on_fix(self, data: dict[str, Any]) -> None:
        """A position fix (the ``position`` stream's data): one control step."""
        try:
            x, y = float(data["x"]), float(data["y"])
            yaw = data.get("yaw")
            yaw = None if yaw is None else float(yaw)
        except (KeyError, TypeError, ValueError):
            return
        if not (math.isfinite(x) and math.isfinite(y)):
            return
        now = self._clock()
        self.last_fix_at = now
        try:
            est = self.observer.update(x, y, yaw, now)
            if self.goal is not None:
                self._step_goal(self.goal, est, now)
            elif self.hold is not None:
                self._step_hold(est, now)
            elif self._driving():
                self._check_drive_motion(est)
            else:
                self._watch_idle(est)
        except Exception:  # a bug here must neither leave the motors running nor take the sensor down
            log.exception("control step failed: motion stopped")
            self.preempt("internal error")
            self._end_drive("internal error")
            self._stop_motors()

    def _step_goal(self, goal: Goal, est: Estimate, now: float) -> None:
        step = goal.controller.step(est)
        goal.last_step = step
        if step.done:
            self._finish(AckStatus.DONE, f"reached: {step.distance_m:.3f} m from the goal")
            return
        wheels = self.kin.mix(step.linear, step.angular)
        why = self._motion_problem(est, wheels)
        if why is not None:
            self._geofence_event("stopped", goal.command_id, est, why)
            self.fail(MotionFailure.GEOFENCE, why)
            return
        if step.distance_m < goal.best - limits.STALL_PROGRESS_M or step.waypoint_index != goal.best_waypoint:
            goal.best, goal.best_at, goal.best_waypoint = step.distance_m, now, step.waypoint_index
        self._apply(goal, wheels)

    def _step_hold(self, est: Estimate, now: float) -> None:
        hold = self.hold
        assert hold is not None
        if now > self.hold_until:
            self.hold = None
            self._stop_motors()
            self.observer.commanded(0.0, 0.0)
            return
        step = hold.controller.step(est)
        wheels = STOPPED if step.done else self.kin.mix(step.linear, step.angular)
        if self._motion_problem(est, wheels) is not None:
            wheels = STOPPED
        self._apply(hold, wheels)

    def _apply(self, goal: Goal, wheels: WheelCommand) -> None:
        try:
            self.motors.set(wheels.left, wheels.right)
        except Exception as exc:
            log.exception("motor error during %s", goal.mode)
            if goal is self.goal:
                self._finish(AckStatus.FAILED, f"motor error: {exc}")
            return
        goal.wheels = wheels
        self.observer.commanded(wheels.linear, wheels.angular)
        self._report(goal, "active", "")

    def tick(self) -> None:
        """Supervision between fixes: no fix, no heartbeat, timeout, no progress; holds that lapsed."""
        now = self._clock()
        goal = self.goal
        if goal is not None:
            fix_age = math.inf if self.last_fix_at is None else now - self.last_fix_at
            if fix_age > limits.FIX_SILENCE_S:
                self.fail(MotionFailure.NO_POSITION, f"no position fix for {fix_age:.2f} s")
            elif not self.supervised(goal.supervisor):
                self.fail(MotionFailure.UNSUPERVISED, self._silence(goal.supervisor))
            elif goal.deadline is not None and now > goal.deadline:
                self.fail(MotionFailure.TIMEOUT, f"after {now - goal.started:.1f} s")
            elif now - goal.best_at > limits.STALL_WINDOW_S:
                self.fail(MotionFailure.STALLED, f"no progress for {now - goal.best_at:.1f} s")
            elif goal.last_step is not None:
                self._report(goal, "active", "")  # keeps the stream at 10 Hz through a fix dropout
        if self.hold is not None and (now > self.hold_until or self.estimate() is None):
            self.hold = None
            self._stop_motors()
            self.observer.commanded(0.0, 0.0)

    async def run(self) -> None:
        while True:  # an idle robot has nothing to supervise: wake it rarely
            await asyncio.sleep(limits.TICK_S if self.active else limits.IDLE_TICK_S)
            try:
                self.tick()
            except Exception:
                log.exception("motion supervision failed: motors stopped")
                self.preempt("internal error")
                self._stop_motors()

    # -- the geofence over drives ---------------------------------------------------------------------
    def _motion_problem(self, est: Estimate, wheels: WheelCommand) -> str | None:
        fence = self.site.fence
        if fence is None or wheels.linear == 0.0:
            return None
        vx = wheels.linear * math.cos(est.yaw) + est.cx
        vy = wheels.linear * math.sin(est.yaw) + est.cy
        return fence.motion_problem(est.x, est.y, vx, vy, self.kin.stop_time_s + limits.LOOKAHEAD_EXTRA_S)

    def check_drive(self, command_id: str, left: float, right: float, duration_s: float) -> str | None:
        """Before a drive command moves the robot: a refusal ("geofence: ...") when it would cross the fence.
        Either way the operator has taken over: a running goal ends."""
        self._end_goal_if_any("superseded by a drive command")
        est = self.estimate()
        if est is not None:
            linear, angular = self.kin.body(left, right)
            why = self._motion_problem(est, WheelCommand(left, right, linear, angular, False))
            if why is not None:
                self._geofence_event("refused", command_id, est, why)
                self._hold_off(est, command_id, duration_s)
                return f"{MotionFailure.GEOFENCE}: {why}"
        self.preempt("superseded by a drive command")
        self.drive_wheels = (left, right)
        return None

    def _check_drive_motion(self, est: Estimate) -> None:
        left, right = self.drive_wheels
        linear, angular = self.kin.body(left, right)
        why = self._motion_problem(est, WheelCommand(left, right, linear, angular, False))
        if why is None:
            return
        self.geofence_stops += 1
        self._geofence_event("stopped", None, est, why)
        self._end_drive(str(MotionFailure.GEOFENCE))
        self._hold_off(est, "hold", 0.5)

    def _hold_off(self, est: Estimate, command_id: str, duration_s: float) -> None:
        """While the operator keeps driving at the fence, hold the spot against the current."""
        self.hold_until = max(self.hold_until, self._clock() + duration_s)
        if self.hold is None:
            ctl = GotoController(est.x, est.y, None, 0.03, 0.05, self.kin)
            now = self._clock()
            self.hold = Goal(command_id, "hold", ctl, {"x": est.x, "y": est.y}, None, self.site.version, now)

    def _watch_idle(self, est: Estimate) -> None:
        fence = self.site.fence
        if fence is None:
            return
        outside = fence.outside_safe(est.x, est.y)
        if outside != self._outside_reported:
            self._outside_reported = outside
            event = "outside" if outside else "inside"
            if outside:
                log.warning("idle robot drifted out of the safe region at (%.3f, %.3f)", est.x, est.y)
            self._geofence_event(event, None, est, "idle: drifting with the water" if outside else "")

    # -- reports -------------------------------------------------------------------------------------
    def _geofence_event(self, event: str, command_id: str | None, est: Estimate, reason: str) -> None:
        if event in ("stopped", "refused"):
            log.warning("geofence %s %s at (%.3f, %.3f): %s", event, command_id or "", est.x, est.y, reason)
        self._emit(GEOFENCE_STREAM, geofence_report(event, command_id, est, reason, self.site.version))

    def _report(self, goal: Goal, state: str, reason: str, force: bool = False) -> None:
        now = self._clock()
        if not force and now - self._last_report < limits.MOTION_REPORT_PERIOD_S:
            return
        self._last_report = now
        self._emit(MOTION_STREAM, goal_report(goal, state, reason, self.observer.est))

    def report_drive(self, command_id: str, wheels: WheelCommand, linear: float, angular: float) -> None:
        """A ``drive`` command's wheel set-points, and what the kinematic limits clamped."""
        self._emit(MOTION_STREAM, drive_report(command_id, wheels, linear, angular, self.site.version))

    def _ack(self, command_id: str, status: AckStatus, reason: str = "") -> None:
        try:
            self._send_ack(make_ack(command_id, status, reason[:500]))
        except Exception:
            log.exception("sending ack failed")

    def _stop_motors(self) -> None:
        try:
            self.motors.stop()
        except Exception:
            log.exception("motor stop failed")
