"""The collision guard: the one safety filter between every motion source and the motors.

It wraps the motor driver, so everything that moves the robot passes through it: held buttons and keys,
``drive``, the seed's commands, ``goto``, ``follow_path``, mission legs, formation set-points and off-board
control. It keeps what it was asked (the *nominal* wheel set-points) and gives the motors that command made
safe (:class:`~robot_agent.motion.avoidance.BarrierFilter`) against the neighbours the servers publish; on
each position fix it filters the nominal command again, as the neighbours move. ``stop``, holds and the e-stop
(:meth:`stop`, :meth:`halt`) go straight to the motors, and a zero command is never changed. A robot parked
after its goal asks the filter what standing still needs (:meth:`keep_clear`; robot_agent/motion/parked.py).

The distance kept to a neighbour's centre is the site's ``min_separation_m`` plus its avoidance margin, plus
what grows with this robot's speed (:data:`SPEED_MARGIN_S` of travel), with the measured drift
(:data:`DRIFT_MARGIN_S`) and with the age of the neighbour's fix. A neighbour whose fix is stale, and every
neighbour while no poses are heard at all, slow the robot to the site's creep speed. Each intervention is a
record on the ``avoidance`` stream (fleet_protocol.neighbours.AvoidanceData). docs/autonomy.md, docs/safety.md.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fleet_protocol import AVOIDANCE_STREAM, AvoidanceSettings
from robot_agent.motion import limits
from robot_agent.motion.avoidance import BarrierFilter, Neighbour
from robot_agent.motion.clock import SYSTEM_CLOCK, Clock
from robot_agent.motion.controller import Estimate
from robot_agent.motion.give_way import GiveWay
from robot_agent.motion.kinematics import Kinematics, WheelCommand
from robot_agent.motion.neighbours import NeighbourTable, NeighbourView
from robot_agent.motors.base import MotorDriver
from robot_agent.sim.world import SimWorld

log = logging.getLogger(__name__)

#: the safety distance grows by this much travel at the commanded speed (a fix period and the actuation)
SPEED_MARGIN_S = 0.1
#: ... and by this much drift at the measured current: as for the speed, a fix period and the actuation (the
#: certificate already counts the drift in this robot's velocity and the neighbour's measured one; 0.5 s kept a
#: formation's followers at 0.46 m held back in the simulator's current: docs/autonomy.md)
DRIFT_MARGIN_S = 0.1
#: the point the filter steers (m ahead of the centre): the safety distance is kept from it plus this much, so a
#: short one keeps robots side by side in a formation at their spacing; 4 cm still lets it move 6 cm/s sideways
LOOKAHEAD_M = 0.04
#: a predicted neighbour is kept clear of by this fraction of full speed times its fix's age more (what it may
#: have turned or slowed since: 6 cm/s of unpredicted velocity at 0.3 m/s; a fix is 0.05-0.25 s old)
AGE_MARGIN = 0.2
#: a neighbour without the filter is kept clear of by this much of its own travel more
UNFILTERED_REACH_S = 1.0
#: neighbours farther than this are not looked at (metres)
RANGE_M = 2.0
#: a change smaller than this is not an intervention (m/s of the body; rad/s)
CHANGED_LINEAR = 0.005
CHANGED_ANGULAR = 0.05
#: records of an intervention while it lasts: at most one per this period
REPORT_PERIOD_S = 0.1
#: a parked robot starts to keep clear only when it must move at least this fast (m/s of its look-ahead point),
#: and goes on until it need not move half as fast: slower is a fix's noise in the measured drift
KEEP_CLEAR_MIN_MPS = 0.01


@dataclass(slots=True)
class _Around:
    """The neighbours in range, as :meth:`GuardedMotors._around` found them."""

    views_by_id: dict[str, NeighbourView]
    near_id: str | None
    near_m: float
    rows: list[Neighbour]
    stale_near: bool


class GuardedMotors(MotorDriver):
    """A motor driver that filters every set-point it is given; see the module's docstring."""

    def __init__(
        self,
        inner: MotorDriver,
        *,
        kinematics: Kinematics,
        neighbours: NeighbourTable,
        emit: Callable[[str, dict[str, Any]], object],
        clock: Clock = SYSTEM_CLOCK,
        server_time: Callable[[], float | None] = lambda: None,
    ) -> None:
        self.inner = inner
        self.kin = kinematics
        self.neighbours = neighbours
        self._emit = emit
        self._clock = clock
        self._server_time = server_time
        self.settings: AvoidanceSettings | None = None
        self._site_known = False
        self.min_separation_m = 0.3
        limits = (kinematics.max_linear_mps, kinematics.max_angular_rps, kinematics.max_wheel_speed_mps)
        self.barrier = BarrierFilter(
            safety_m=self.min_separation_m,
            range_m=RANGE_M,
            lookahead_m=LOOKAHEAD_M,
            pass_right_rad=0.6,
            centre_safety=True,
            limits=(*limits, kinematics.wheel_base_m),
        )
        self.nominal: tuple[float, float] = (0.0, 0.0)
        self.applied: tuple[float, float] = (0.0, 0.0)
        self._pose: Estimate | None = None
        self._pose_at = -math.inf
        #: the running intervention: (cause, neighbour, started at, last reported at); None while none
        self._intervention: tuple[str, str | None, float, float] | None = None
        #: when the filter last changed a command (monotonic; -inf: never)
        self.last_intervention_at = -math.inf
        #: the neighbour of the latest intervention and its distance (centre to centre)
        self.last_held_by: tuple[str | None, float] = (None, math.inf)
        #: a goal's wanted ground velocity, for the filter to keep to near others (set with set_goal)
        self.intent: tuple[float, float] | None = None
        self.give_way = GiveWay(neighbours.own_id)
        #: a parked robot's command while it keeps clear (:meth:`keep_clear`); None while it stands still
        self.keeping_clear: WheelCommand | None = None

    # -- MotorDriver --------------------------------------------------------------------------------------
    @classmethod
    def create(cls, config: Any, world: SimWorld | None) -> MotorDriver:
        raise TypeError("GuardedMotors wraps a driver: build it with GuardedMotors(inner, ...)")

    def set(self, left: float, right: float) -> None:
        self.nominal, self.intent, self.keeping_clear = (left, right), None, None
        self._apply()

    def set_goal(self, left: float, right: float, intent: tuple[float, float] | None) -> None:
        """A goal's set-points, with the ground velocity its controller wants (Step.intent)."""
        self.nominal, self.intent, self.keeping_clear = (left, right), intent, None
        self._apply()

    def stop(self) -> None:
        """Straight to the motors: a stop is never filtered."""
        self.nominal, self.intent, self.keeping_clear = (0.0, 0.0), None, None
        self.applied = (0.0, 0.0)
        self.inner.stop()
        self._end_intervention(self._clock.monotonic())

    def operable(self) -> tuple[bool, str]:
        return self.inner.operable()

    def close(self) -> None:
        self.nominal = (0.0, 0.0)
        self.inner.close()

    @property
    def motor_fault(self) -> bool | None:
        return self.inner.motor_fault

    # -- inputs ---------------------------------------------------------------------------------------------
    def configure(self, settings: AvoidanceSettings | None, min_separation_m: float | None) -> None:
        """The site's settings (None: a site from a server without the filter: the robot runs without it)."""
        self.settings = settings
        self._site_known = True
        if min_separation_m is not None:
            self.min_separation_m = min_separation_m

    @property
    def enabled(self) -> bool:
        return self.settings is not None and self.settings.enabled

    def on_poses_payload(self, payload: bytes) -> None:
        self.neighbours.on_payload(payload, self._clock.monotonic(), self._server_time())

    def on_pose(self, est: Estimate) -> None:
        """A position fix: where this robot is (the runner's estimate, with its drift)."""
        self._pose, self._pose_at = est, self._clock.monotonic()
        self.give_way.on_pose(self._pose_at, est.x, est.y)

    def refresh(self) -> None:
        """Filter the running command again against where everyone is now (each fix of a drive)."""
        with self.watchdog.lock:  # never between a watchdog trip and its stop
            if self.nominal != (0.0, 0.0) and self.filtered(*self.nominal) != self.applied:
                self._apply()

    def hears_poses(self) -> bool | None:
        """Whether the filter hears the fleet's poses (None once a site turned it off): the health stream's
        ``hears_poses``, which the server's readiness reads. Before the first site it tells what it hears: a
        robot just started is not ready until the poses come."""
        if self._site_known and not self.enabled:
            return None
        return self.neighbours.heard_recently(self._clock.monotonic())

    def goal_problem(self) -> str | None:
        """Why a new goal must wait: with the filter on, a robot that hears no poses knows nothing of its
        neighbours."""
        now = self._clock.monotonic()
        if self.enabled and not self.neighbours.heard_recently(now):
            silence = self.neighbours.silence_s(now)
            heard = "never" if math.isinf(silence) else f"not for {silence:.1f} s"
            return f"no_poses: the fleet's poses were {heard} heard; new goals wait for them"
        return None

    def held_back_by(self) -> str:
        """Who held the robot back last, for a goal's ``failed: blocked`` reason."""
        robot_id, dist = self.last_held_by
        if robot_id is None:
            return "another robot in the way" if math.isinf(dist) else "no fleet poses heard"
        return f"held back by {robot_id} ({dist:.2f} m away)"

    def held_back_since(self, since: float) -> bool:
        """The filter changed a command at or after ``since`` (monotonic)."""
        return self.last_intervention_at >= since

    # -- the filter -----------------------------------------------------------------------------------------
    def _apply(self) -> None:
        left, right = self.filtered(*self.nominal)
        self.applied = (left, right)
        self.inner.set(left, right)

    def filtered(self, left: float, right: float) -> tuple[float, float]:
        """The wheel set-points to give the motors for the nominal ``left``, ``right``."""
        now = self._clock.monotonic()
        est = self._fresh_pose(now)
        if (left == 0.0 and right == 0.0) or not self.enabled or est is None:
            self._end_intervention(now)  # without its own fix the robot cannot tell: its goals stop anyway
            return left, right
        settings = self.settings
        assert settings is not None
        linear, angular = self.kin.body(left, right)
        drift = (est.cx, est.cy)
        base = settings.margin_m + SPEED_MARGIN_S * abs(linear) + DRIFT_MARGIN_S * math.hypot(*drift)
        base += self.min_separation_m
        cause, creep = "", False
        if not self.neighbours.heard_recently(now):
            cause, creep = "no_poses", True
        around = self._around(now, est, base)
        views_by_id, near_id, near_m, rows = around.views_by_id, around.near_id, around.near_m, around.rows
        if around.stale_near:  # contact possible since a neighbour's fix
            creep = True
            cause = cause or "stale"
        yielding = self.give_way.velocity(now, est.x, est.y)
        if yielding is not None:
            out = self.barrier.filter_point(est.x, est.y, est.yaw, yielding, rows, drift)
            cause = cause or "give_way"
        else:
            out = self.barrier.filter(est.x, est.y, est.yaw, linear, angular, rows, drift, self.intent)
            if out.changed:
                self.give_way.held(now, views_by_id.get(near_id or ""))
        v, w = out.linear, out.angular
        if creep and abs(v) > settings.creep_mps:
            v = math.copysign(settings.creep_mps, v)
        changed = abs(v - linear) > CHANGED_LINEAR or abs(w - angular) > CHANGED_ANGULAR
        if not changed:
            self._end_intervention(now)
            return left, right
        wheels = self.kin.mix(v, w)
        if not cause and out.nearest_id in views_by_id:  # the barrier's: the neighbour nearest its look-ahead
            held_by = views_by_id[out.nearest_id]
            near_id, near_m = held_by.robot_id, math.hypot(held_by.x - est.x, held_by.y - est.y)
        applied = (wheels.linear, wheels.angular)
        self._intervene(now, cause or "barrier", near_id, near_m, base, (linear, angular), applied)
        return wheels.left, wheels.right

    def _fresh_pose(self, now: float) -> Estimate | None:
        """This robot's pose, when its last fix is recent enough to act on."""
        return self._pose if now - self._pose_at <= limits.FIX_SILENCE_S else None

    def _around(self, now: float, est: Estimate, base: float) -> _Around:
        """The neighbours in range as the filter's rows, the nearest, and whether a stale one is near enough
        that contact is possible since its fix."""
        out = _Around({}, None, math.inf, [], False)
        for n in self.neighbours.views(now, est.x, est.y, RANGE_M):
            out.views_by_id[n.robot_id] = n
            dist = math.hypot(n.x - est.x, n.y - est.y)
            if dist < out.near_m:
                out.near_id, out.near_m = n.robot_id, dist
            out.rows.append(self._row(n, (n.x - est.x) / max(dist, 1e-9), (n.y - est.y) / max(dist, 1e-9), base))
            if n.stale and dist < base + n.age_s * self.kin.max_linear_mps:
                out.stale_near = True
        return out

    # -- a parked robot keeps clear ------------------------------------------------------------------------
    def keep_clear(self) -> WheelCommand | None:
        """What a parked robot must do so that no neighbour, nor the water, brings it inside the safety
        distance: the filter of standing still (motors off, the drift still carrying it), or None when standing
        still is safe. Only the robot's own drift and the neighbours' measured motion ask for it, and less than
        :data:`KEEP_CLEAR_MIN_MPS` (a fix's noise in the drift) starts nothing. The caller decides when a robot
        may keep clear at all (robot_agent/motion/parked.py: after a goal ended by itself, never after a stop,
        the e-stop or a lost link)."""
        now = self._clock.monotonic()
        est = self._fresh_pose(now)
        if not self.enabled or est is None or not self.neighbours.heard_recently(now):
            self.end_keep_clear()
            return None
        settings = self.settings
        assert settings is not None
        drift = (est.cx, est.cy)
        base = self.min_separation_m + settings.margin_m + DRIFT_MARGIN_S * math.hypot(*drift)
        around = self._around(now, est, base)
        out = self.barrier.filter_point(est.x, est.y, est.yaw, (0.0, 0.0), around.rows, drift)
        point_mps = math.hypot(out.linear, LOOKAHEAD_M * out.angular)
        starts = point_mps >= (KEEP_CLEAR_MIN_MPS if self.keeping_clear is None else KEEP_CLEAR_MIN_MPS / 2)
        if not out.changed or not starts:
            self.end_keep_clear()
            return None
        wheels = self.kin.mix(out.linear, out.angular)
        held_by = around.views_by_id.get(out.nearest_id or "")
        near_id, near_m = around.near_id, around.near_m
        if held_by is not None:
            near_id, near_m = held_by.robot_id, math.hypot(held_by.x - est.x, held_by.y - est.y)
        self.keeping_clear = wheels
        self.applied = (wheels.left, wheels.right)
        self.inner.set(wheels.left, wheels.right)
        self._intervene(now, "keep_clear", near_id, near_m, base, (0.0, 0.0), (wheels.linear, wheels.angular))
        return wheels

    def end_keep_clear(self) -> None:
        """A parked robot that was keeping clear stands still again (motors off)."""
        if self.keeping_clear is not None:
            self.keeping_clear = None
            self.stop()

    def _row(self, n: NeighbourView, ex: float, ey: float, base: float) -> Neighbour:
        """A neighbour's certificate (``ex, ey``: the way to it). Kept ``base`` from its centre to this robot's
        centre (the barrier adds the look-ahead as far as the robot faces away from it: ``centre_safety``), plus
        what its fix's age leaves unknown. A stale one: from where it was, taking all the
        avoidance. A filtering one takes its half, and only its moving away counts (a leader ahead of its
        followers is no threat). One without the filter (the old framework) gets none of it: its whole
        velocity counts, and a second of its travel more."""
        safety = base  # between centres: the filter adds the look-ahead where the heading asks it (centre_safety)
        if n.stale:  # where it is now is unknown: keep to where it was (and creep near it, above)
            return Neighbour(n.robot_id, n.x, n.y, cooperative=False, safety_m=safety)
        safety += AGE_MARGIN * self.kin.max_linear_mps * n.age_s  # a prediction: it may have turned or slowed
        if n.filtered:
            away = max(0.0, n.vx * ex + n.vy * ey)
            return Neighbour(n.robot_id, n.x, n.y, away * ex, away * ey, safety_m=safety, course=(n.vx, n.vy))
        reach = UNFILTERED_REACH_S * math.hypot(n.vx, n.vy)
        return Neighbour(n.robot_id, n.x, n.y, n.vx, n.vy, cooperative=False, safety_m=safety + reach)

    # -- the avoidance stream -------------------------------------------------------------------------------
    def _intervene(
        self,
        now: float,
        cause: str,
        neighbour: str | None,
        distance_m: float,
        safety_m: float,
        nominal: tuple[float, float],
        applied: tuple[float, float],
    ) -> None:
        self.last_intervention_at = now
        self.last_held_by = (neighbour, distance_m)
        run = self._intervention
        if run is None or run[0] != cause:
            self._end_intervention(now)
            run = (cause, neighbour, now, -math.inf)
        if now - run[3] < REPORT_PERIOD_S:
            return
        self._intervention = (cause, neighbour, run[2], now)
        self._record("active", cause, neighbour, distance_m, safety_m, nominal, applied, now - run[2])

    def _end_intervention(self, now: float) -> None:
        run, self._intervention = self._intervention, None
        if run is not None:
            self._record("cleared", run[0], run[1], None, None, (0.0, 0.0), (0.0, 0.0), now - run[2])

    def _record(
        self,
        event: str,
        cause: str,
        neighbour: str | None,
        distance_m: float | None,
        safety_m: float | None,
        nominal: tuple[float, float],
        applied: tuple[float, float],
        duration_s: float,
    ) -> None:
        try:
            self._emit(
                AVOIDANCE_STREAM,
                {
                    "event": event,
                    "cause": cause,
                    "neighbour": neighbour,
                    "distance_m": None if distance_m is None or math.isinf(distance_m) else round(distance_m, 4),
                    "safety_m": None if safety_m is None else round(safety_m, 4),
                    "linear": round(nominal[0], 4),
                    "angular": round(nominal[1], 4),
                    "filtered_linear": round(applied[0], 4),
                    "filtered_angular": round(applied[1], 4),
                    "duration_s": round(duration_s, 3),
                },
            )
        except Exception:  # a report must never take the motors' filter down
            log.exception("avoidance record failed")
