"""The formation control law: a follower holds a slot fixed in its leader's frame (docs/autonomy.md,
"Formation").

Pure functions of the poses and their timestamps (no I/O, no clock, no paho), so the same code runs in an
off-board controller (``examples/formation.py`` through ``client.control``) and in the server's
``formation`` mission, and in a fast offline simulation.

Why it is built this way:

- The slot moves with the leader *and turns with it*: its velocity is the leader's velocity plus
  ``omega x r`` (the leader's turn rate times the slot's lever arm). Both are fed forward, so the follower
  does not wait for an error to build before it moves. The inner follower of a turn therefore gets a
  lower speed and the same turn rate, i.e. a tighter turn, without a special case.
- The leader's pose, velocity and turn rate come from a least-squares line through its last 0.75 s of
  fixes (one Lighthouse fix is noisy, ~5 mm and 0.01 rad) and are extrapolated to the moment the
  follower's set-point reaches its wheels: the measured age of the fixes plus the actuation lead
  (link and motor latency). The follower's own pose is predicted to the same moment from its last
  set-point, so latency does not turn into lag.
- The water current is a slow drift; a proportional pull alone would sit ``current / k_pos`` behind the
  slot. An integral of the slot error (clamped, frozen while the error is large or the command saturates)
  is the current estimate that cancels it.
- The robot is a differential drive: it cannot move sideways. The law steers a point a little ahead of
  the hull (its look-ahead grows with speed, so the heading loop stays slower than the loop's delay
  allows): for that point (linear, angular) follow exactly from the desired velocity. The hull is turned
  towards the steady water-relative velocity, with the leader's turn rate fed forward. A follower faces
  the way the formation travels and backs up along its heading (never turns round) when it is ahead of
  its slot.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field


def wrap(a: float) -> float:
    """An angle in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


@dataclass(frozen=True, slots=True)
class FormationGains:
    """The law's tuning (defaults: the simulator's robots, wheel base 0.2 m, wheel speed 0.3 m/s)."""

    #: Proportional pull towards the slot, m/s per metre of error.
    k_pos: float = 1.2
    #: Integral action (the current estimate), m/s per metre-second of error, and its clamp (m/s).
    k_int: float = 0.4
    max_int_mps: float = 0.05
    #: The integral only learns while the follower is this close to its slot (not from a transient).
    int_zone_m: float = 0.08
    #: Heading loop: rad/s per radian of heading error.
    k_heading: float = 2.0
    #: The controlled point's distance ahead of the hull centre (m): smaller turns harder on a sideways error;
    #: at speed it is ``lookahead_s`` times the speed (the heading loop's gain is at most 1 / lookahead_s).
    lookahead_m: float = 0.05
    lookahead_s: float = 0.4
    #: Below this water-relative speed (m/s) the hull mostly keeps its heading instead of turning to it.
    heading_blend_mps: float = 0.01
    #: Limits of the set-points (the robot's kinematics clamp them again).
    max_speed_mps: float = 0.2
    max_turn_rps: float = 1.5
    #: Closer than this to a slot that stands still: stand still too (no turning on the fix noise).
    settled_m: float = 0.02
    #: The leader's fit window (s): long enough to average the fix noise, short enough to follow its turns.
    window_s: float = 0.75
    #: Time from a set-point to the wheels (link to the robot + actuation latency), s: predicted over.
    actuation_lead_s: float = 0.06
    #: A leader fix older than this is no basis for a set-point (the follower stops).
    max_leader_age_s: float = 0.5
    #: Predict at most this far ahead (a stale pose is not extrapolated into fiction).
    max_predict_s: float = 0.3


@dataclass(frozen=True, slots=True)
class LeaderState:
    """The leader's pose, ground velocity (m/s, world frame) and turn rate (rad/s) at one moment."""

    x: float
    y: float
    yaw: float
    vx: float
    vy: float
    omega: float


@dataclass
class LeaderTrack:
    """A least-squares line through the leader's recent fixes: its pose, velocity and turn rate, lag-free
    for steady motion and averaged over ``window_s`` of noise."""

    window_s: float = 0.75
    _fixes: deque[tuple[float, float, float, float]] = field(default_factory=lambda: deque(maxlen=400))

    def update(self, x: float, y: float, yaw: float, ts: float) -> None:
        """Add a fix (``ts`` in seconds, any epoch shared with :meth:`state`); old or repeated ones are ignored."""
        if not all(math.isfinite(v) for v in (x, y, yaw, ts)):
            return
        if self._fixes:
            last_t, _, _, last_yaw = self._fixes[-1]
            if ts <= last_t:
                return
            if ts - last_t > self.window_s:  # a gap: the old line says nothing about now
                self._fixes.clear()
            else:
                yaw = last_yaw + wrap(yaw - last_yaw)  # unwrapped, so a line fits through it
        self._fixes.append((ts, x, y, yaw))
        while len(self._fixes) > 2 and ts - self._fixes[0][0] > self.window_s:
            self._fixes.popleft()

    @property
    def last_ts(self) -> float | None:
        return self._fixes[-1][0] if self._fixes else None

    def state(self, t: float) -> LeaderState | None:
        """The fitted state extrapolated to ``t``; None before the first fix."""
        if not self._fixes:
            return None
        n = len(self._fixes)
        t_last, x_last, y_last, yaw_last = self._fixes[-1]
        if n < 3 or t_last - self._fixes[0][0] < 0.2:  # too short a line: the last fix, standing
            return LeaderState(x_last, y_last, wrap(yaw_last), 0.0, 0.0, 0.0)
        tm = sum(f[0] for f in self._fixes) / n
        stt = sum((f[0] - tm) ** 2 for f in self._fixes)
        out: list[float] = []
        for k in (1, 2, 3):
            mean = sum(f[k] for f in self._fixes) / n
            slope = sum((f[0] - tm) * (f[k] - mean) for f in self._fixes) / stt
            out += [mean + slope * (t - tm), slope]
        x, vx, y, vy, yaw, omega = out
        return LeaderState(x, y, wrap(yaw), vx, vy, omega)


def slot_position(leader: LeaderState, offset: tuple[float, float]) -> tuple[float, float]:
    """Where a slot (``offset`` = metres forward, metres left, in the leader's frame) is in the world."""
    c, s = math.cos(leader.yaw), math.sin(leader.yaw)
    return leader.x + offset[0] * c - offset[1] * s, leader.y + offset[0] * s + offset[1] * c


def slot_velocity(leader: LeaderState, offset: tuple[float, float]) -> tuple[float, float]:
    """The slot's ground velocity: the leader's plus ``omega x r`` (r the slot's lever arm in the world)."""
    c, s = math.cos(leader.yaw), math.sin(leader.yaw)
    rx, ry = offset[0] * c - offset[1] * s, offset[0] * s + offset[1] * c
    return leader.vx - leader.omega * ry, leader.vy + leader.omega * rx


@dataclass
class SlotFollower:
    """One follower's controller: call :meth:`step` on each of its own fixes, with its leader's track."""

    offset: tuple[float, float]
    gains: FormationGains = field(default_factory=FormationGains)
    #: The integral of the slot error (m*s, world frame): what holds the follower against the current.
    ix: float = 0.0
    iy: float = 0.0
    _last_t: float | None = None
    _cmd: tuple[float, float] = (0.0, 0.0)
    _reverse: bool = False
    #: The last step's slot error (m), for reports.
    error_m: float = 0.0

    def reset(self) -> None:
        """Forget the last set-point (the robot was stopped); keep the current estimate."""
        self._cmd = (0.0, 0.0)
        self._last_t = None

    def step(self, x: float, y: float, yaw: float, ts: float, leader: LeaderTrack, now: float) -> tuple[float, float]:
        """(linear m/s, angular rad/s) from the follower's fix (x, y, yaw at ``ts``) and the leader's
        track, ``now`` on the same clock as the fixes' ``ts``. (0, 0) when the leader's fixes are stale."""
        g = self.gains
        last = leader.last_ts
        if last is None or now - last > g.max_leader_age_s:
            self.reset()
            return 0.0, 0.0
        # The moment this set-point acts: the follower's fix age plus the actuation lead.
        ahead = min(max(now - ts, 0.0) + g.actuation_lead_s, g.max_predict_s)
        lead = leader.state(min(now + g.actuation_lead_s, last + g.max_predict_s))
        assert lead is not None
        v0, w0 = self._cmd
        yaw_p = yaw + w0 * ahead
        mid = yaw + w0 * ahead / 2
        px, py = x + v0 * math.cos(mid) * ahead, y + v0 * math.sin(mid) * ahead
        sx, sy = slot_position(lead, self.offset)
        fx, fy = slot_velocity(lead, self.offset)
        ex, ey = sx - px, sy - py
        err = math.hypot(ex, ey)
        self.error_m = err
        dt = 0.0 if self._last_t is None else min(max(ts - self._last_t, 0.0), 0.2)
        self._last_t = ts
        # Desired ground velocity: feed-forward + P + I (the I learns only near the slot: anti-windup).
        ux = fx + g.k_pos * ex + g.k_int * self.ix
        uy = fy + g.k_pos * ey + g.k_int * self.iy
        speed = math.hypot(ux, uy)
        if err < g.int_zone_m and speed < g.max_speed_mps:
            self.ix += ex * dt
            self.iy += ey * dt
            lim = g.max_int_mps / g.k_int if g.k_int > 0 else 0.0
            norm = math.hypot(self.ix, self.iy)
            if norm > lim:
                self.ix, self.iy = self.ix * lim / norm, self.iy * lim / norm
        moving = math.hypot(lead.vx, lead.vy) > 0.01 or abs(lead.omega) > 0.02
        if err < g.settled_m and not moving:
            self._cmd = (0.0, 0.0)
            return self._cmd
        # The heading to hold: along the steady water-relative velocity (slot velocity minus the current),
        # or its reverse when that is nearer the hull (hysteresis: no flipping on a sideways error); with
        # no such velocity, the hull's own heading.
        wx, wy = fx + g.k_int * self.ix, fy + g.k_int * self.iy
        wn = math.hypot(wx, wy)
        if wn > 1e-4:
            off = abs(wrap(math.atan2(wy, wx) - yaw_p))
            if off > math.radians(110):
                self._reverse = True
            elif off < math.radians(70):
                self._reverse = False
        sign = -1.0 if self._reverse else 1.0
        hx, hy = math.cos(yaw_p), math.sin(yaw_p)
        blend = wn / (wn + g.heading_blend_mps)
        tx = blend * sign * wx / max(wn, 1e-9) + (1 - blend) * hx
        ty = blend * sign * wy / max(wn, 1e-9) + (1 - blend) * hy
        tn = math.hypot(tx, ty) or 1.0
        tx, ty = tx / tn, ty / tn
        # Control a point d ahead of the hull in its direction of travel (exactly linearizable for a
        # differential drive: forward speed moves it along the hull, turning moves it sideways); its
        # target is the slot plus d along the heading to hold. The turn rate this gives a heading error is
        # speed / d, so d grows with the speed: the heading loop stays slower than the loop's delay allows.
        bx, by = fx + g.k_pos * ex + g.k_int * self.ix, fy + g.k_pos * ey + g.k_int * self.iy
        base = min(math.hypot(bx, by), g.max_speed_mps)
        d = sign * max(g.lookahead_m, base * g.lookahead_s)
        omega_ff = lead.omega if moving else 0.0
        ux = bx + d * (g.k_heading * (tx - hx) - omega_ff * ty)
        uy = by + d * (g.k_heading * (ty - hy) + omega_ff * tx)
        un = math.hypot(ux, uy)
        if un > g.max_speed_mps:  # saturate the velocity as a whole: its direction (the steering) stays
            ux, uy = ux * g.max_speed_mps / un, uy * g.max_speed_mps / un
        linear = ux * hx + uy * hy
        angular = (-ux * hy + uy * hx) / d
        angular = max(-g.max_turn_rps, min(g.max_turn_rps, angular))
        linear = max(-g.max_speed_mps, min(g.max_speed_mps, linear))
        self._cmd = (linear, angular)
        return self._cmd
