"""The motion runner: goals (goto, follow_path) in a control loop on the robot's own position fixes, their
supervision, and the geofence over every motion (goals, ``drive``, the seed's held drive commands).

It runs on the agent's asyncio loop. A control step runs on each position fix (the sensor rate);
:meth:`MotionRunner.tick` (every 25 ms) ends a goal that lost its fix (0.3 s), its supervision (no server
heartbeat for 1 s; or, for a goal that names its ``supervisor``, none from that server replica: another replica's
beat does not keep it going), its time or its progress. The command handler tells the runner (``preempt``) when a
stop, the e-stop, a lost link, shutdown or another drive ends what it is doing; goals are then acked
``aborted`` (or ``failed: link_lost``) and the motors stopped.

Every read of time and every sleep goes through ``clock`` (real by default; a twin's may be virtual). Beside it:
the server heartbeats (``supervision``), the fence's checks and events (``fence_guard``), goal plans (``goal``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

from fleet_protocol import (
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
)
from robot_agent.motion import limits
from robot_agent.motion.clock import SYSTEM_CLOCK, Clock
from robot_agent.motion.collision_guard import GuardedMotors
from robot_agent.motion.controller import DriftObserver, Estimate, GotoController
from robot_agent.motion.fence_guard import FenceGuard
from robot_agent.motion.geofence import SiteState
from robot_agent.motion.goal import Goal, Plan, drive_report, goal_report, path_points, plan_goto, plan_path
from robot_agent.motion.kinematics import STOPPED, Kinematics, WheelCommand
from robot_agent.motion.parked import Parked
from robot_agent.motion.supervision import ServerBeats
from robot_agent.motors.base import MotorDriver
from robot_agent.util import RejectCounter

log = logging.getLogger(__name__)


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
        clock: Clock = SYSTEM_CLOCK,
    ) -> None:
        self.kin = kinematics
        self.motors = motors
        #: the safety filter, when the motors are behind it (the agent's always are)
        self.collision = motors if isinstance(motors, GuardedMotors) else None
        self._send_ack = send_ack
        self._emit = emit
        self._end_drive = end_drive
        self._driving = driving
        self._clock = clock
        self.guard = FenceGuard(kinematics=kinematics, emit=emit)
        self.beats = ServerBeats(clock)
        self.observer = DriftObserver()
        self.rejects = RejectCounter(log)
        self.goal: Goal | None = None
        self.hold: Goal | None = None  # station keeping after the geofence stopped a held drive
        self.hold_until = 0.0
        self.parked = Parked(
            collision=self.collision, fence=self.guard, observer=self.observer, supervised=self._supervised
        )
        self.drive_wheels: tuple[float, float] = (0.0, 0.0)  # set-points of the running drive command
        self.last_fix_at: float | None = None
        self._last_report = 0.0
        self.geofence_stops = 0

    # -- inputs ------------------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        """A goal, a hold-off or keeping clear is moving the robot (the link watchdog watches while this is
        true)."""
        return self.goal is not None or self.hold is not None or self.parked.moving

    @property
    def site(self) -> SiteState:
        return self.guard.site

    def on_heartbeat_payload(self, payload: bytes) -> None:
        try:
            hb = decode_heartbeat(payload)
        except ProtocolError as exc:
            self.rejects.reject(exc.reason, exc.detail)
            return
        self.beats.heard(hb.server_id)

    def on_site_payload(self, payload: bytes) -> None:
        try:
            msg = decode_site(payload)
        except ProtocolError as exc:
            self.rejects.reject(exc.reason, exc.detail)
            return
        self.guard.site = SiteState.from_message(msg)
        if self.collision is not None:
            self.collision.configure(msg.avoidance, None if msg.site is None else msg.site.min_separation_m)
        log.info("site received: %s", self.site.describe())

    def estimate(self) -> Estimate | None:
        """The filtered pose, when the last fix is recent enough to act on."""
        if self.last_fix_at is None or self._clock.monotonic() - self.last_fix_at > limits.FIX_SILENCE_S:
            return None
        return self.observer.est

    # -- starting goals ------------------------------------------------------------------------------
    def _refusal(
        self, points: list[tuple[float, float]], closed: bool, supervisor: str | None, est: Estimate | None
    ) -> str | None:
        if not self.site.received:
            return "no site received yet: goals need the site (its geofence) first"
        if not self.beats.supervised(supervisor):
            source = f"server {supervisor}" if supervisor else "server"
            return f"{MotionFailure.UNSUPERVISED}: no {source} heartbeat in the last {HEARTBEAT_SILENCE_S} s"
        if est is None:
            return f"{MotionFailure.NO_POSITION}: no position fix"
        if self.collision is not None and (why := self.collision.goal_problem()) is not None:
            return why
        return self.guard.goal_problem(points, closed, est)

    def _accepted(
        self, command_id: str, points: list[tuple[float, float]], closed: bool, supervisor: str | None
    ) -> Estimate | None:
        """The pose to plan the goal from; None when it is refused (and acked ``rejected`` with the reason)."""
        est = self.estimate()
        why = self._refusal(points, closed, supervisor, est)
        if why is not None:
            self._ack(command_id, AckStatus.REJECTED, why)
            return None
        return est

    def start_goto(self, command_id: str, args: GotoArgs) -> None:
        est = self._accepted(command_id, [(args.x, args.y)], False, args.supervisor)
        if est is not None:
            self._begin(command_id, plan_goto(args, est, self.kin), args.supervisor)

    def start_path(self, command_id: str, args: FollowPathArgs) -> None:
        est = self._accepted(command_id, path_points(args), args.loop, args.supervisor)
        if est is not None:
            self._begin(command_id, plan_path(args, est, self.kin), args.supervisor)

    def _begin(self, command_id: str, plan: Plan, supervisor: str | None) -> None:
        self._end_drive("superseded by " + plan.mode)  # ends a running drive; preempt() aborts a running goal
        self._end_goal_if_any("superseded by " + plan.mode)
        now = self._clock.monotonic()
        self.goal = Goal(
            command_id,
            plan.mode,
            plan.controller,
            plan.goal,
            None if plan.timeout is None else now + plan.timeout,
            self.site.version,
            now,
            best_at=now,
            supervisor=supervisor,
        )
        self._ack(command_id, AckStatus.ACCEPTED, f"checked against {self.site.describe()}")
        log.info("%s %s started (%s)", plan.mode, command_id, plan.goal)

    # -- ending --------------------------------------------------------------------------------------
    def _supervised(self) -> bool:
        return self.beats.supervised(None)

    def preempt(self, reason: str) -> None:
        """Something else took the motors (a stop, e-stop, lost link, shutdown, another drive): it stays parked
        where it is until a goal ends by itself again."""
        self.hold = None
        self._end_goal_if_any(reason)
        self.parked.disarm()

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
        self.parked.armed = status != AckStatus.ABORTED and not reason.startswith(MotionFailure.LINK_LOST)
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
        now = self._clock.monotonic()
        self.last_fix_at = now
        try:
            est = self.observer.update(x, y, yaw, now)
            if self.collision is not None:
                self.collision.on_pose(est)
            if self.goal is not None:
                self._step_goal(self.goal, est, now)
            elif self.hold is not None:
                self._step_hold(est, now)
            elif self._driving():
                self._check_drive_motion(est)
                if self.collision is not None:
                    self.collision.refresh()
            else:
                self.guard.watch_idle(est)
                self.parked.step(est)
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
        why = self.guard.motion_problem(est, wheels)
        if why is not None:
            self.guard.event("stopped", goal.command_id, est, why)
            self.fail(MotionFailure.GEOFENCE, why)
            return
        if step.distance_m < goal.best - limits.STALL_PROGRESS_M or step.waypoint_index != goal.best_waypoint:
            goal.best, goal.best_at, goal.best_waypoint = step.distance_m, now, step.waypoint_index
        self._apply(goal, wheels, step.intent)

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
        if self.guard.motion_problem(est, wheels) is not None:
            wheels = STOPPED
        self._apply(hold, wheels)

    def _apply(self, goal: Goal, wheels: WheelCommand, intent: tuple[float, float] | None = None) -> None:
        try:
            if self.collision is not None:
                self.collision.set_goal(wheels.left, wheels.right, intent)
            else:
                self.motors.set(wheels.left, wheels.right)
        except Exception as exc:
            log.exception("motor error during %s", goal.mode)
            if goal is self.goal:
                self._finish(AckStatus.FAILED, f"motor error: {exc}")
            return
        goal.wheels = wheels
        if self.collision is not None:  # the observer models what the motors really got
            self.observer.commanded(*self.kin.body(*self.collision.applied))
        else:
            self.observer.commanded(wheels.linear, wheels.angular)
        self._report(goal, "active", "")

    def tick(self) -> None:
        """Supervision between fixes: no fix, no heartbeat, timeout, no progress; holds that lapsed."""
        now = self._clock.monotonic()
        goal = self.goal
        if goal is not None:
            fix_age = math.inf if self.last_fix_at is None else now - self.last_fix_at
            if fix_age > limits.FIX_SILENCE_S:
                self.fail(MotionFailure.NO_POSITION, f"no position fix for {fix_age:.2f} s")
            elif not self.beats.supervised(goal.supervisor):
                self.fail(MotionFailure.UNSUPERVISED, self.beats.silence(goal.supervisor))
            elif goal.deadline is not None and now > goal.deadline:
                self.fail(MotionFailure.TIMEOUT, f"after {now - goal.started:.1f} s")
            elif now - goal.best_at > limits.STALL_WINDOW_S and not self._held_back(goal):
                self.fail(MotionFailure.STALLED, f"no progress for {now - goal.best_at:.1f} s")
            elif now - goal.best_at > limits.BLOCKED_WINDOW_S:
                assert self.collision is not None  # only a held-back goal gets here
                why = f"no progress for {now - goal.best_at:.1f} s: {self.collision.held_back_by()}"
                self.fail(MotionFailure.BLOCKED, why)
            elif goal.last_step is not None:
                self._report(goal, "active", "")  # keeps the stream at 10 Hz through a fix dropout
        if self.hold is not None and (now > self.hold_until or self.estimate() is None):
            self.hold = None
            self._stop_motors()
            self.observer.commanded(0.0, 0.0)
        if self.parked.moving and (self.estimate() is None or not self._supervised()):
            self.parked.halt()  # without its fix or the server it cannot tell: it stands until they are back

    def _held_back(self, goal: Goal) -> bool:
        """The safety filter changed this goal's commands since its last progress: it is blocked, not stalled."""
        return self.collision is not None and self.collision.held_back_since(goal.best_at)

    async def run(self) -> None:
        while True:  # an idle robot has nothing to supervise: wake it rarely
            await self._clock.sleep(limits.TICK_S if self.active else limits.IDLE_TICK_S)
            try:
                self.tick()
            except Exception:
                log.exception("motion supervision failed: motors stopped")
                self.preempt("internal error")
                self._stop_motors()

    # -- the geofence over drives ---------------------------------------------------------------------
    def check_drive(self, command_id: str, left: float, right: float, duration_s: float) -> str | None:
        """Before a drive command moves the robot: a refusal ("geofence: ...") when it would cross the fence.
        Either way the operator has taken over: a running goal ends."""
        self._end_goal_if_any("superseded by a drive command")
        est = self.estimate()
        if est is not None:
            why = self.guard.drive_problem(est, left, right)
            if why is not None:
                self.guard.event("refused", command_id, est, why)
                self._hold_off(est, command_id, duration_s)
                return f"{MotionFailure.GEOFENCE}: {why}"
        self.preempt("superseded by a drive command")
        self.drive_wheels = (left, right)
        return None

    def _check_drive_motion(self, est: Estimate) -> None:
        why = self.guard.drive_problem(est, *self.drive_wheels)
        if why is None:
            return
        self.geofence_stops += 1
        self.guard.event("stopped", None, est, why)
        self._end_drive(str(MotionFailure.GEOFENCE))
        self._hold_off(est, "hold", 0.5)

    def _hold_off(self, est: Estimate, command_id: str, duration_s: float) -> None:
        """While the operator keeps driving at the fence, hold the spot against the current."""
        self.hold_until = max(self.hold_until, self._clock.monotonic() + duration_s)
        if self.hold is None:
            ctl = GotoController(est.x, est.y, None, 0.03, 0.05, self.kin)
            now = self._clock.monotonic()
            self.hold = Goal(command_id, "hold", ctl, {"x": est.x, "y": est.y}, None, self.site.version, now)

    # -- reports -------------------------------------------------------------------------------------
    def _report(self, goal: Goal, state: str, reason: str, force: bool = False) -> None:
        now = self._clock.monotonic()
        if not force and now - self._last_report < limits.MOTION_REPORT_PERIOD_S:
            return
        self._last_report = now
        self._emit(MOTION_STREAM, goal_report(goal, state, reason, self.observer.est))

    def report_drive(self, command_id: str, wheels: WheelCommand, linear: float, angular: float) -> None:
        """A ``drive`` command's wheel set-points, and what the kinematic limits clamped."""
        self._emit(MOTION_STREAM, drive_report(command_id, wheels, linear, angular, self.site.version))

    def _ack(self, command_id: str, status: AckStatus, reason: str = "") -> None:
        try:
            self._send_ack(Ack(id=command_id, status=status, reason=reason[:500], ts=self._clock.now()))
        except Exception:
            log.exception("sending ack failed")

    def _stop_motors(self) -> None:
        try:
            self.motors.stop()
        except Exception:
            log.exception("motor stop failed")
