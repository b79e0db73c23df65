"""The goal controllers: a drift observer on the Lighthouse fixes, go-to-point and path following.

Pure functions of the pose estimate (no I/O, no clock), so they run the same in the agent's control loop
and in a fast offline simulation. Design and reasons: docs/autonomy.md, "Control design".

In short: the robot is a differential-drive swimmer (it cannot move sideways) in water that carries it.
The controller decides the *ground* velocity it wants (towards the goal, or along the path and back onto
it), subtracts the estimated water current (the integral term: the observer integrates the part of the
motion its model does not explain), and steers the hull along the resulting water-relative velocity,
turning first when the heading is far off. It slows down near the goal and before sharp corners.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from robot_agent.motion.kinematics import Kinematics


def wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


@dataclass
class Estimate:
    x: float
    y: float
    yaw: float
    #: Estimated water current (m/s, world frame): the drift the controller compensates.
    cx: float = 0.0
    cy: float = 0.0


class DriftObserver:
    """An alpha-beta filter of the fixes. The model is the commanded body velocity plus the drift; ``alpha``
    pulls the estimate to each fix (smoothing the ~5 mm noise), ``beta`` integrates what stays unexplained
    into the drift, which is what lets the controller hold a line or a point against a current.

    A Lighthouse source that gives no heading (``yaw`` None: some of the old modules) gets one from the way
    the robot moves through the water while it drives straight (its track minus the drift)."""

    def __init__(
        self, alpha: float = 0.35, beta: float = 0.006, yaw_alpha: float = 0.5, max_drift_mps: float = 0.1
    ) -> None:
        self.alpha = alpha
        self.beta = beta
        self.yaw_alpha = yaw_alpha
        self.max_drift = max_drift_mps
        self.est: Estimate | None = None
        self._t: float | None = None
        # body velocity commanded one and two steps ago: the older one is what moved the robot since the last
        # fix (actuation latency and the motors' lag are about one control period)
        self._cmd = [(0.0, 0.0), (0.0, 0.0)]
        self._track: list[tuple[float, float, float]] = []  # recent (t, x, y) estimates, for a missing yaw

    def reset(self) -> None:
        """Forget the pose (keep the drift: the water does not change because a goal ended)."""
        self._t = None

    def commanded(self, linear: float, angular: float) -> None:
        self._cmd = [(linear, angular), self._cmd[0]]

    def update(self, x: float, y: float, yaw: float | None, t: float) -> Estimate:
        est = self.est
        if est is None or self._t is None or t - self._t > 1.0:
            keep = (est.cx, est.cy) if est is not None else (0.0, 0.0)
            self.est = Estimate(x, y, yaw if yaw is not None else (est.yaw if est else 0.0), *keep)
            self._t = t
            return self.est
        dt = max(t - self._t, 1e-3)
        self._t = t
        v, w = self._cmd[1]
        mid_yaw = est.yaw + w * dt / 2
        px = est.x + (v * math.cos(mid_yaw) + est.cx) * dt
        py = est.y + (v * math.sin(mid_yaw) + est.cy) * dt
        pyaw = wrap(est.yaw + w * dt)
        rx, ry = x - px, y - py
        est.x = px + self.alpha * rx
        est.y = py + self.alpha * ry
        est.yaw = pyaw if yaw is None else wrap(pyaw + self.yaw_alpha * wrap(yaw - pyaw))
        if yaw is None:
            self._heading_from_track(t, v, w)
        est.cx += self.beta * rx / dt
        est.cy += self.beta * ry / dt
        n = math.hypot(est.cx, est.cy)
        if n > self.max_drift:
            est.cx, est.cy = est.cx * self.max_drift / n, est.cy * self.max_drift / n
        return est

    def _heading_from_track(self, t: float, v: float, w: float) -> None:
        est = self.est
        assert est is not None
        if abs(v) < 0.03 or abs(w) > 0.3:  # only a straight run says where the hull points
            self._track.clear()
            return
        self._track.append((t, est.x, est.y))
        while self._track and t - self._track[0][0] > 0.5:
            self._track.pop(0)
        t0, x0, y0 = self._track[0]
        span = t - t0
        dx, dy = est.x - x0 - est.cx * span, est.y - y0 - est.cy * span
        if span < 0.3 or math.hypot(dx, dy) < 0.03:
            return
        heading = math.atan2(dy, dx) if v > 0 else math.atan2(-dy, -dx)
        est.yaw = wrap(est.yaw + 0.2 * wrap(heading - est.yaw))


@dataclass(frozen=True, slots=True)
class Gains:
    #: Heading loop (rad/s per rad) and the heading error beyond which the robot only turns.
    k_heading: float = 2.5
    turn_first_rad: float = 0.8
    #: Approach: ground speed = k_approach * distance (slows near the goal), at least min_speed.
    k_approach: float = 0.8
    min_speed_mps: float = 0.02
    #: Path: how hard the robot steers back onto the line (1/s).
    k_cross: float = 1.5
    #: Goal reached when the estimate is within this fraction of the tolerance (the fixes are noisy).
    done_fraction: float = 0.6
    yaw_tolerance_rad: float = 0.1


@dataclass(frozen=True, slots=True)
class Step:
    linear: float
    angular: float
    distance_m: float
    done: bool = False
    cross_track_m: float | None = None
    waypoint_index: int | None = None
    #: the ground velocity (m/s, world frame) the controller wants: what the safety filter keeps to near others
    intent: tuple[float, float] | None = None


def steer(est: Estimate, gx: float, gy: float, kin: Kinematics, g: Gains, reverse_ok: bool) -> tuple[float, float]:
    """Body velocity that makes the robot's ground velocity (gx, gy): water-relative = ground - current,
    heading along it; turn in place first when far off, or back up when that is shorter (near a goal)."""
    wx, wy = gx - est.cx, gy - est.cy
    speed = math.hypot(wx, wy)
    if speed < 1e-6:
        return 0.0, 0.0
    err = wrap(math.atan2(wy, wx) - est.yaw)
    direction = 1.0
    if reverse_ok and abs(err) > math.pi / 2:
        err = wrap(err - math.pi)
        direction = -1.0
    angular = g.k_heading * err
    if abs(err) > g.turn_first_rad:
        return 0.0, angular
    return direction * speed * math.cos(err), angular


class GotoController:
    def __init__(
        self,
        x: float,
        y: float,
        yaw: float | None,
        tolerance_m: float,
        max_speed: float,
        kin: Kinematics,
        gains: Gains | None = None,
    ) -> None:
        self.x, self.y, self.yaw = x, y, yaw
        self.tol = tolerance_m
        self.max_speed = min(max_speed, kin.max_linear_mps)
        self.kin = kin
        self.g = gains or Gains()
        self._aligning = False

    def step(self, est: Estimate) -> Step:
        g = self.g
        ex, ey = self.x - est.x, self.y - est.y
        d = math.hypot(ex, ey)
        inner = self.tol * g.done_fraction
        if self.yaw is None:
            if d < inner:
                return Step(0.0, 0.0, d, done=True)
        else:
            if d < inner:
                self._aligning = True
            elif d > self.tol * 0.9:
                self._aligning = False
            if self._aligning:
                yaw_err = wrap(self.yaw - est.yaw)
                if abs(yaw_err) < g.yaw_tolerance_rad:
                    return Step(0.0, 0.0, d, done=True)
                # turn, and hold the spot along the heading against the current meanwhile
                wx, wy = g.k_approach * ex - est.cx, g.k_approach * ey - est.cy
                along = wx * math.cos(est.yaw) + wy * math.sin(est.yaw)
                return Step(along, g.k_heading * yaw_err, d)
        speed = min(self.max_speed, max(g.min_speed_mps, g.k_approach * d))
        intent = (ex / d * speed, ey / d * speed)
        linear, angular = steer(est, *intent, self.kin, g, reverse_ok=d < 0.15)
        return Step(linear, angular, d, intent=intent)


class PathFollower:
    """Follows the polyline start -> waypoints (-> first waypoint again, forever, with ``loop``)."""

    def __init__(
        self,
        start: tuple[float, float],
        waypoints: list[tuple[float, float]],
        tolerance_m: float,
        max_speed: float,
        loop: bool,
        kin: Kinematics,
        gains: Gains | None = None,
    ) -> None:
        self.points = [start]
        self._index = [-1]  # index in ``waypoints`` of each point
        for i, p in enumerate(waypoints):  # a repeated point is no leg
            if p != self.points[-1]:
                self.points.append(p)
                self._index.append(i)
        if len(self.points) == 1:
            self.points.append(start)
            self._index.append(len(waypoints) - 1)
        self._count = len(waypoints)
        self.loop = loop
        self.tol = tolerance_m
        self.max_speed = min(max_speed, kin.max_linear_mps)
        self.kin = kin
        self.g = gains or Gains()
        self.leg = 0  # from points[leg] to points[leg + 1]
        self.laps = 0

    @property
    def waypoint_count(self) -> int:
        return self._count

    @property
    def waypoint_index(self) -> int:
        """Index in the given waypoints of the one the robot is heading for."""
        return self._index[self.leg + 1]

    def _next_index(self, i: int) -> int:
        """Index (in ``points``) after ``i``; looping skips the start point."""
        return i + 1 if i + 1 < len(self.points) else 1

    def _last_leg(self) -> bool:
        return not self.loop and self.leg + 1 >= len(self.points) - 1

    def remaining(self, est: Estimate) -> float:
        """Path length left: to the current leg's end, then the legs after it (one lap for a loop)."""
        bx, by = self.points[self.leg + 1]
        total = math.hypot(bx - est.x, by - est.y)
        if not self.loop:
            for a, b in zip(self.points[self.leg + 1 :], self.points[self.leg + 2 :], strict=False):
                total += math.dist(a, b)
        return total

    def step(self, est: Estimate) -> Step:
        g = self.g
        for _ in range(len(self.points) + 1):  # at most one lap of leg switches per fix
            ax, ay = self.points[self.leg]
            bx, by = self.points[self.leg + 1]
            sx, sy = bx - ax, by - ay
            length = math.hypot(sx, sy)
            to_end = math.hypot(bx - est.x, by - est.y)
            if length < 1e-9:
                along, cross = 0.0, 0.0
            else:
                along = ((est.x - ax) * sx + (est.y - ay) * sy) / length
                cross = ((est.x - ax) * sy - (est.y - ay) * sx) / length  # + = right of the leg
            left_on_leg = length - along
            if self._last_leg():
                if to_end < self.tol * g.done_fraction:
                    return Step(0.0, 0.0, to_end, True, abs(cross), self.waypoint_index)
                break
            # switch legs at the corner: when past it, or within the distance the robot covers while turning
            if left_on_leg > max(0.02, self.tol * 0.5) and to_end > self.tol * 0.5:
                break
            nxt = self._next_index(self.leg + 1)
            if nxt == 1 and self.loop:
                self.laps += 1
                self.points[0] = self.points[-1]
                self.leg = 0
            else:
                self.leg += 1
        tx, ty = (sx / length, sy / length) if length > 1e-9 else (0.0, 0.0)
        speed = self.max_speed
        if self._last_leg():
            speed = min(speed, max(g.min_speed_mps, g.k_approach * to_end))
        else:
            cx2, cy2 = self.points[self._next_index(self.leg + 1)]
            turn = abs(wrap(math.atan2(cy2 - by, cx2 - bx) - math.atan2(sy, sx)))
            corner_speed = self.max_speed * min(1.0, max(0.2, math.cos(turn)))
            speed = min(speed, corner_speed + g.k_approach * max(0.0, left_on_leg))
        # along the leg, and back onto it (cross > 0: right of the leg, so steer left)
        back = max(-self.max_speed, min(self.max_speed, g.k_cross * cross))
        nx, ny = -ty, tx  # left normal
        gx, gy = tx * speed + nx * back, ty * speed + ny * back
        linear, angular = steer(est, gx, gy, self.kin, g, reverse_ok=False)
        return Step(linear, angular, self.remaining(est), False, abs(cross), self.waypoint_index, (gx, gy))
