"""Robot-to-robot avoidance: a minimally invasive safety filter on the commanded body velocity.

The method is the safety barrier certificate of Wang, Ames and Egerstedt, "Safety Barrier Certificates for
Collisions-Free Multirobot Systems", IEEE Transactions on Robotics 33(3), 2017 (the filter the Robotarium
passes every command through). Why it suits a drifting, underactuated swimmer, and how it is tuned: docs/
autonomy.md, "Robots never collide".

- A unicycle cannot move sideways, so the filter works on a point ``lookahead_m`` ahead of the robot, which
  can (a near-identity diffeomorphism): its velocity ``u = R(yaw) [v, lookahead * w]``.
- For each neighbour ``j`` with ``d = p - p_j`` (between the look-ahead points) the barrier is
  ``h = |d|^2 - D^2`` with ``D`` the safety distance, and the certificate asks
  ``-2 d . (u - u_j) <= share * gamma * h``: a linear class-K function, so the gap may close at most
  exponentially, with time constant ``1 / gamma`` (the Robotarium's ``h^3`` holds robots back from well
  outside the safety distance, which spoilt formations at their spacing). ``share`` is 1/2 when the
  neighbour runs the filter too (each takes half of the avoidance) and 1 when it does not (an old-framework
  robot, or one whose pose is stale: this robot takes all of it); ``u_j`` is the neighbour's measured velocity.
- The command is changed as little as it can be: ``min |u - u_nom|^2`` subject to the certificates, a
  quadratic programme in two variables solved exactly by Seidel's incremental method (:func:`solve_qp`).

- No deadlock: two robots that meet head-on would each slide along the other's barrier and could stop face to
  face. When a certificate binds and the neighbour is in the way, the command is turned to the right
  (``pass_right_rad``, growing as the gap closes) before the filter makes it safe: every robot passes every
  other on its right, as ships do (COLREGs, rule 14). This is the "small perturbation" of Wang et al., made
  consistent; a command no certificate holds back is never turned.
- A jam of several robots can still lock, each held by another. The robots give way by rank: one that has not
  moved for a while, held back by a neighbour whose id sorts before its own, backs off to the right of it for
  a moment (robot_agent/motion/collision_guard.py): in any jam the first robot is never held by one that waits
  for it, so the jam unwinds.
- A drift (the water's current, measured by the robot's observer) is part of the robot's velocity: the
  certificate holds for the command plus the drift.

A zero command stays zero (the filter never adds motion); when no velocity satisfies every certificate the
robot stops. A parked robot that must keep clear asks :meth:`BarrierFilter.filter_point` for the velocity zero
itself (robot_agent/motion/parked.py). ``stop``, holds and the e-stop never reach the filter: they bypass it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: below this a command is zero, and a constraint's normal is degenerate
EPS = 1e-9


@dataclass(frozen=True, slots=True)
class Neighbour:
    """A neighbour as this robot knows it: its look-ahead point's place and velocity (m, m/s) and whether it
    takes its half of the avoidance."""

    robot_id: str
    x: float
    y: float
    vx: float = 0.0
    vy: float = 0.0
    cooperative: bool = True
    #: the distance kept from this neighbour (None: the filter's ``safety_m``); grows with its fix's age
    safety_m: float | None = None
    #: its whole measured velocity, for the course judged by :meth:`BarrierFilter.passing_turn` (None: ``vx``,
    #: ``vy``). The certificate may count less of it (only a leader's moving away), but whether this robot is on
    #: a collision course with it depends on where it really goes: a follower keeping pace is on none
    course: tuple[float, float] | None = None


@dataclass(frozen=True, slots=True)
class Filtered:
    """The command after the filter: body velocity, whether it changed, and the nearest neighbour's distance."""

    linear: float
    angular: float
    changed: bool
    nearest_id: str | None = None
    nearest_m: float = math.inf


@dataclass(frozen=True, slots=True)
class BarrierFilter:
    """``safety_m``: the distance kept between look-ahead points; ``gamma``: how fast the filter lets a robot
    approach the boundary of the safe set (larger: later and harder); ``range_m``: neighbours farther than this
    are not looked at."""

    safety_m: float
    lookahead_m: float = 0.08
    gamma: float = 4.0
    #: kept beyond ``safety_m``: between two control steps a unicycle's look-ahead point curves off the straight
    #: line the certificate assumes, and the neighbour's velocity changes (measured: up to 9 mm at 20 Hz)
    step_margin_m: float = 0.01
    range_m: float = 3.0
    #: the turn to the right before a neighbour being closed on (radians, at the safety distance)
    pass_right_rad: float = 0.0
    #: the right turn starts this far outside the safety distance
    pass_right_range_m: float = 0.25
    #: True: a neighbour's ``safety_m`` is kept between centres, and the look-ahead point keeps it plus the
    #: look-ahead only as far as the robot faces away from the neighbour (:meth:`safety`). False: the look-ahead
    #: point keeps ``safety_m`` whatever its heading
    centre_safety: bool = False
    #: what the robot can do (m/s, rad/s, each wheel's m/s, wheel base m); None: anything. The filtered command
    #: is chosen within them: a command the motors then clamp could break a certificate the filter relied on
    limits: tuple[float, float, float, float] | None = None

    def lookahead_point(self, x: float, y: float, yaw: float) -> tuple[float, float]:
        return x + self.lookahead_m * math.cos(yaw), y + self.lookahead_m * math.sin(yaw)

    def safety(self, n: Neighbour, px: float, py: float, yaw: float | None) -> float:
        """The distance the look-ahead point ``(px, py)`` keeps from ``n``'s centre. With :attr:`centre_safety`
        the centre is to keep ``safety_m``: it lies the look-ahead behind the point, so the point keeps
        ``safety_m`` plus the look-ahead times how far the heading points away from the neighbour (facing it,
        the centre is farther than the point and ``safety_m`` is enough). A turn away moves the point away
        twice as fast as this grows, so turning never breaks it. A follower facing its leader's way keeps
        its slot; a robot backing towards a neighbour keeps the whole look-ahead more."""
        safety = self.safety_m if n.safety_m is None else n.safety_m
        if not self.centre_safety or yaw is None:
            return safety
        dx, dy = n.x - px, n.y - py
        dist = math.hypot(dx, dy)
        if dist < EPS:
            return safety + self.lookahead_m
        facing = (math.cos(yaw) * dx + math.sin(yaw) * dy) / dist
        return safety + self.lookahead_m * max(0.0, -facing)

    def constraints(
        self,
        px: float,
        py: float,
        neighbours: list[Neighbour],
        drift: tuple[float, float] = (0.0, 0.0),
        yaw: float | None = None,
    ) -> list[tuple[float, float, float]]:
        """Each neighbour's certificate as a half-plane ``a . u <= b`` of the look-ahead point's velocity
        (``yaw``: the robot's heading, for :meth:`safety`)."""
        out = []
        for n in neighbours:
            dx, dy = px - n.x, py - n.y
            dist2 = dx * dx + dy * dy
            if dist2 > self.range_m * self.range_m or dist2 < EPS:
                continue
            safety = self.safety(n, px, py, yaw) + self.step_margin_m
            h = dist2 - safety * safety
            share = 0.5 if n.cooperative else 1.0
            # -2 d . (u + drift - u_j) <= share * gamma * h
            b = share * self.gamma * h - 2.0 * (dx * (n.vx - drift[0]) + dy * (n.vy - drift[1]))
            ax, ay = -2.0 * dx, -2.0 * dy
            if self.limits is not None and math.hypot(ax, ay) * self._max_point_speed() <= b:
                continue  # no velocity the robot can reach comes near it: it can never bind
            out.append((ax, ay, b))
        return out

    def _max_point_speed(self) -> float:
        """The fastest the look-ahead point can move within :attr:`limits`."""
        assert self.limits is not None
        max_linear, max_angular, _, _ = self.limits
        return math.hypot(max_linear, self.lookahead_m * max_angular)

    def kinematic_rows(self, yaw: float) -> list[tuple[float, float, float]]:
        """:attr:`limits` as half-planes of the look-ahead point's velocity (heading ``yaw``): the body's
        speed and turn, and each wheel's speed (``|v| + |w| b / 2 <= wheel``)."""
        if self.limits is None:
            return []
        max_linear, max_angular, wheel, base = self.limits
        c, s, look = math.cos(yaw), math.sin(yaw), self.lookahead_m
        # v = c ux + s uy ; w = (-s ux + c uy) / look
        v_row, w_row = (c, s), (-s / look, c / look)
        rows = []
        for sign in (1.0, -1.0):
            rows.append((sign * v_row[0], sign * v_row[1], max_linear))
            rows.append((sign * w_row[0], sign * w_row[1], max_angular))
            for turn_sign in (1.0, -1.0):
                k = turn_sign * base / 2
                rows.append((sign * v_row[0] + k * w_row[0], sign * v_row[1] + k * w_row[1], wheel))
        return rows

    def passing_turn(self, px: float, py: float, ux: float, uy: float, neighbours: list[Neighbour]) -> float:
        """How far to turn the command right (radians) before the nearest neighbour on a collision course with
        it. The course is the motion relative to the neighbour (``u - u_j``): a follower keeping pace beside
        or behind its leader is on no course with it and is not turned off its slot."""
        if self.pass_right_rad <= 0.0:
            return 0.0
        turn = 0.0
        for n in neighbours:
            dx, dy = n.x - px, n.y - py
            dist = math.hypot(dx, dy)
            nvx, nvy = (n.vx, n.vy) if n.course is None else n.course
            rx, ry = ux - nvx, uy - nvy
            speed = math.hypot(rx, ry)
            if dist < EPS or speed < EPS or dx * rx + dy * ry <= 0.0:
                continue  # not closing on it
            safety = self.safety_m if n.safety_m is None else n.safety_m
            if self.centre_safety:  # the course is judged at the distance the point kept before centre_safety
                safety += self.lookahead_m
            miss = abs(rx * dy - ry * dx) / speed
            if miss >= safety:
                continue  # closing on it, but the course passes clear of it
            closeness = 1.0 - (dist - safety) / self.pass_right_range_m
            head_on = min(1.0, 2.0 * (1.0 - miss / safety))
            turn = max(turn, self.pass_right_rad * min(max(closeness, 0.0), 1.0) * head_on)
        return turn

    def filter(
        self,
        x: float,
        y: float,
        yaw: float,
        linear: float,
        angular: float,
        neighbours: list[Neighbour],
        drift: tuple[float, float] = (0.0, 0.0),
        intent: tuple[float, float] | None = None,
    ) -> Filtered:
        """The command (``linear`` m/s, ``angular`` rad/s) of a robot at ``(x, y, yaw)``, made safe.

        ``intent``: the ground velocity the robot's controller wants (a goal's direction and speed). Where the
        filter has to step in, it keeps to that rather than to the heading controller's command: a robot
        turning on the spot asks its look-ahead point to go sideways, which is not where it means to go."""
        if abs(linear) < EPS and abs(angular) < EPS:
            return Filtered(0.0, 0.0, False, *self.nearest(x, y, yaw, neighbours))
        c, s = math.cos(yaw), math.sin(yaw)
        ux = c * linear - s * self.lookahead_m * angular
        uy = s * linear + c * self.lookahead_m * angular
        out = self.filter_point(x, y, yaw, (ux, uy), neighbours, drift)
        if out.changed and intent is not None:
            out = self.filter_point(x, y, yaw, (intent[0] - drift[0], intent[1] - drift[1]), neighbours, drift)
            out = Filtered(out.linear, out.angular, True, out.nearest_id, out.nearest_m)
        return out if out.changed else Filtered(linear, angular, False, out.nearest_id, out.nearest_m)

    def nearest(self, x: float, y: float, yaw: float, neighbours: list[Neighbour]) -> tuple[str | None, float]:
        px, py = self.lookahead_point(x, y, yaw)
        nearest_id, nearest = None, math.inf
        for n in neighbours:
            d = math.hypot(px - n.x, py - n.y)
            if d < nearest:
                nearest_id, nearest = n.robot_id, d
        return nearest_id, nearest

    def filter_point(
        self,
        x: float,
        y: float,
        yaw: float,
        u: tuple[float, float],
        neighbours: list[Neighbour],
        drift: tuple[float, float] = (0.0, 0.0),
    ) -> Filtered:
        """The look-ahead point's velocity ``u`` (m/s, world frame) made safe, as a body command."""
        px, py = self.lookahead_point(x, y, yaw)
        nearest_id, nearest = self.nearest(x, y, yaw, neighbours)
        ux, uy = u
        rows = self.constraints(px, py, neighbours, drift, yaw)
        if not rows:
            return Filtered(*self._body(yaw, ux, uy), False, nearest_id, nearest)  # nobody near: as asked
        rows += self.kinematic_rows(yaw)
        best = solve_qp(ux, uy, rows)
        if best is not None and abs(best[0] - ux) < 1e-7 and abs(best[1] - uy) < 1e-7:
            return Filtered(*self._body(yaw, ux, uy), False, nearest_id, nearest)  # no certificate binds
        turn = self.passing_turn(px, py, ux, uy, neighbours)  # a certificate binds: pass on the right
        if turn > 0.0:
            ct, st = math.cos(turn), math.sin(turn)
            best = solve_qp(ct * ux + st * uy, -st * ux + ct * uy, rows)
        if best is None:  # nothing the robot can do satisfies every certificate: get away as fast as it can
            best = self._escape(px, py, yaw, neighbours)
        if best is None:
            return Filtered(0.0, 0.0, True, nearest_id, nearest)
        fx, fy = best
        return Filtered(*self._body(yaw, fx, fy), True, nearest_id, nearest)

    def _escape(self, px: float, py: float, yaw: float, neighbours: list[Neighbour]) -> tuple[float, float] | None:
        """Away from the neighbours inside their safety distance (the nearer, the more), as fast as the wheels
        allow: a neighbour that does not slow down (the old framework) is outrun where it can be."""
        ax = ay = 0.0
        for n in neighbours:
            dx, dy = px - n.x, py - n.y
            dist = math.hypot(dx, dy)
            safety = self.safety(n, px, py, yaw) + self.step_margin_m
            if EPS < dist < safety:
                ax, ay = ax + dx / dist * (safety - dist), ay + dy / dist * (safety - dist)
        norm = math.hypot(ax, ay)
        if norm < EPS or self.limits is None:
            return None
        speed = self._max_point_speed()
        return solve_qp(ax / norm * speed, ay / norm * speed, self.kinematic_rows(yaw))

    def _body(self, yaw: float, ux: float, uy: float) -> tuple[float, float]:
        """The body command (m/s, rad/s) that moves the look-ahead point at ``(ux, uy)``."""
        c, s = math.cos(yaw), math.sin(yaw)
        return c * ux + s * uy, (-s * ux + c * uy) / self.lookahead_m


def solve_qp(ux: float, uy: float, rows: list[tuple[float, float, float]]) -> tuple[float, float] | None:
    """``argmin |u - (ux, uy)|^2`` subject to ``a . u <= b`` for each row ``(ax, ay, b)``; None if infeasible.

    Exact, by Seidel's incremental method (R. Seidel, "Small-dimensional linear programming and convex hulls
    made easy", Discrete Comput. Geom. 6, 1991; it holds for any strictly convex objective): the rows are taken
    one at a time, keeping the optimum of those taken so far. A row the optimum satisfies changes nothing; one
    it violates holds with equality at the new optimum, which is then the nearest point to ``u`` on that row's
    line within the rows before it: a one-dimensional interval. At most ``m^2 / 2`` row products for ``m``
    rows, and far fewer in practice (a control tick with twenty neighbours: issue 31's 1 ms on a Pi 5)."""
    x, y = ux, uy
    for i, (ax, ay, b) in enumerate(rows):
        if ax * x + ay * y <= b + 1e-9 * (1.0 + abs(b)):
            continue
        n2 = ax * ax + ay * ay
        if n2 < EPS:
            return None  # 0 <= b with b < 0: nothing satisfies it
        # the line's point nearest u, and its direction: x = p + t d, cost |p - u|^2 + t^2 |d|^2
        k = (ax * ux + ay * uy - b) / n2
        px, py, dx, dy = ux - k * ax, uy - k * ay, -ay, ax
        lo, hi = -math.inf, math.inf
        for cx, cy, c in rows[:i]:
            slope = cx * dx + cy * dy
            room = c - (cx * px + cy * py)
            if abs(slope) < EPS * n2:  # parallel to the line: all of it or none of it
                if room < -1e-9 * (1.0 + abs(c)):
                    return None
            elif slope > 0.0:
                hi = min(hi, room / slope)
            else:
                lo = max(lo, room / slope)
        if lo > hi + 1e-9 * (1.0 + abs(hi)):
            return None
        t = min(max(0.0, lo), hi)
        x, y = px + t * dx, py + t * dy
    return x, y
