"""Simulated robot in a pool: differential-drive kinematics integrated on demand, plus AprilTags on the walls.

Integration happens whenever the state is read or the wheels are set, in sub-steps of at most
``max_step_s`` (default 5 ms, i.e. >= 200 Hz) from the elapsed monotonic time, so the pose is exact for the
commanded wheel speeds without a background task, and reads from any thread are consistent (one lock).
Wheel speeds follow their set-points with a first-order lag (``motor_tau_s``) so the simulated IMU sees
finite accelerations. With a :class:`~robot_agent.sim.disturbances.Disturbance` the water current moves the
robot (also while stopped), set-points arrive after a latency and the wheels are off by asymmetry and
noise, and :meth:`SimWorld.lighthouse_fix` is noisy and drops out now and then.
"""

from __future__ import annotations

import hashlib
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from robot_agent.sim.disturbances import Disturbance

GRAVITY = 9.81


@dataclass(frozen=True, slots=True)
class Pose:
    x: float
    y: float
    yaw: float


@dataclass(frozen=True, slots=True)
class SimTag:
    """A tag36h11 AprilTag in the world: centre (x, y, z) metres, printed face looking towards ``yaw``."""

    id: int
    size_m: float
    x: float
    y: float
    z: float
    yaw: float

    @property
    def position(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.z)


@dataclass(frozen=True, slots=True)
class PoolBounds:
    xmin: float = -2.0
    xmax: float = 2.0
    ymin: float = -2.0
    ymax: float = 2.0


def default_tags(bounds: PoolBounds = PoolBounds(), size_m: float = 0.1, z: float = 0.1) -> list[SimTag]:
    """Four tags, one in the middle of each pool wall, facing the pool (at the camera's mount height)."""
    return [
        SimTag(0, size_m, bounds.xmax, 0.0, z, math.pi),  # east wall, looking west
        SimTag(1, size_m, 0.0, bounds.ymax, z, -math.pi / 2),  # north wall, looking south
        SimTag(2, size_m, bounds.xmin, 0.0, z, 0.0),  # west wall, looking east
        SimTag(3, size_m, 0.0, bounds.ymin, z, math.pi / 2),  # south wall, looking north
    ]


def start_pose_for(robot_id: str, bounds: PoolBounds = PoolBounds(), margin: float = 0.5) -> Pose:
    """A deterministic start pose from a hash of the robot id, inside the pool (away from the walls)."""
    h = hashlib.sha256(robot_id.encode()).digest()
    u = [int.from_bytes(h[i : i + 4], "big") / 2**32 for i in (0, 4, 8)]
    x = bounds.xmin + margin + u[0] * (bounds.xmax - bounds.xmin - 2 * margin)
    y = bounds.ymin + margin + u[1] * (bounds.ymax - bounds.ymin - 2 * margin)
    return Pose(x, y, (u[2] * 2 - 1) * math.pi)


def wrap_angle(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


@dataclass
class _State:
    x: float
    y: float
    yaw: float
    v_left: float = 0.0  # m/s
    v_right: float = 0.0
    target_left: float = 0.0
    target_right: float = 0.0
    accel_fwd: float = 0.0  # m/s^2, body x
    t: float = 0.0


@dataclass
class SimWorld:
    """One simulated differential-drive robot. ``set_wheels`` takes fractions of ``max_speed_mps``."""

    start: Pose = field(default_factory=lambda: Pose(0.0, 0.0, 0.0))
    max_speed_mps: float = 0.3
    wheel_base_m: float = 0.2
    motor_tau_s: float = 0.02
    bounds: PoolBounds = field(default_factory=PoolBounds)
    robot_radius_m: float = 0.1
    tags: list[SimTag] = field(default_factory=default_tags)
    max_step_s: float = 0.005
    clock: Callable[[], float] = time.monotonic
    #: The honest simulator's disturbances (None = a perfect world).
    disturbance: Disturbance | None = None

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self._s = _State(self.start.x, self.start.y, wrap_angle(self.start.yaw), t=self.clock())
        self._t0 = self._s.t
        self.wall_hits = 0
        #: Set-points on their way to the wheels (actuation latency): (time they arrive, left, right).
        self._pending: deque[tuple[float, float, float]] = deque()
        self._applied = (0.0, 0.0)  # set-points (fractions) that have reached the wheels
        #: A test's fault injection (SIGUSR2 on a simulated agent): the Lighthouse gives no fix while set.
        self.lighthouse_blackout = False

    # -- integration ------------------------------------------------------------------------------
    def _advance(self) -> None:
        now = self.clock()
        while self._pending and self._pending[0][0] <= now:
            at, left, right = self._pending.popleft()
            self._integrate(at)
            self._applied = (left, right)
            self._apply_targets(at)
        self._integrate(now)

    def _apply_targets(self, t: float) -> None:
        """Wheel targets (m/s) for the set-points at the wheels, with asymmetry and noise as of ``t``."""
        left, right = self._applied
        gl, gr = (1.0, 1.0) if self.disturbance is None else self.disturbance.wheel_factors(t - self._t0)
        self._s.target_left = left * gl * self.max_speed_mps
        self._s.target_right = right * gr * self.max_speed_mps

    def _integrate(self, now: float) -> None:
        s = self._s
        dt_total = now - s.t
        if dt_total <= 0:
            return
        n = max(1, math.ceil(dt_total / self.max_step_s))
        dt = dt_total / n
        tau = self.motor_tau_s
        k = 1.0 if tau <= 0 else 1.0 - math.exp(-dt / tau)
        # mean of the first-order response over one sub-step (exact): target + (v0 - target) * m
        m = 0.0 if tau <= 0 else tau / dt * k
        b = self.bounds
        r = self.robot_radius_m
        v_prev = (s.v_left + s.v_right) / 2
        d = self.disturbance
        for i in range(n):
            if d is not None and d.noise_on:  # a new noise draw changes the wheel targets, not the set-points
                self._apply_targets(s.t + i * dt)
            cx_w, cy_w = (0.0, 0.0) if d is None else d.current(s.t + i * dt - self._t0)
            s.x += cx_w * dt
            s.y += cy_w * dt
            vl = s.target_left + (s.v_left - s.target_left) * m
            vr = s.target_right + (s.v_right - s.target_right) * m
            s.v_left += (s.target_left - s.v_left) * k
            s.v_right += (s.target_right - s.v_right) * k
            if abs(s.v_left - s.target_left) < 1e-4:  # settled (0.1 mm/s): snap, so a stopped robot is still
                s.v_left = s.target_left
            if abs(s.v_right - s.target_right) < 1e-4:
                s.v_right = s.target_right
            v = (vl + vr) / 2
            w = (vr - vl) / self.wheel_base_m
            if abs(w) < 1e-9:
                s.x += v * dt * math.cos(s.yaw)
                s.y += v * dt * math.sin(s.yaw)
            else:  # exact arc for constant v, w over the sub-step
                yaw1 = s.yaw + w * dt
                s.x += v / w * (math.sin(yaw1) - math.sin(s.yaw))
                s.y -= v / w * (math.cos(yaw1) - math.cos(s.yaw))
                s.yaw = yaw1
            cx = min(max(s.x, b.xmin + r), b.xmax - r)
            cy = min(max(s.y, b.ymin + r), b.ymax - r)
            if cx != s.x or cy != s.y:
                self.wall_hits += 1
                s.x, s.y = cx, cy
        s.yaw = wrap_angle(s.yaw)
        s.accel_fwd = ((s.v_left + s.v_right) / 2 - v_prev) / dt_total
        s.t = now

    # -- API ----------------------------------------------------------------------------------------
    def set_wheels(self, left: float, right: float) -> None:
        """Wheel set-points as fractions (-1..1) of ``max_speed_mps`` (reaching the wheels after the latency)."""
        left = min(max(float(left), -1.0), 1.0)
        right = min(max(float(right), -1.0), 1.0)
        with self._lock:
            self._advance()
            delay = 0.0 if self.disturbance is None else self.disturbance.latency()
            if delay <= 0.0 and not self._pending:
                self._applied = (left, right)
                self._apply_targets(self._s.t)
            else:  # in order: a later set-point never overtakes an earlier one
                at = max(self._s.t + delay, self._pending[-1][0] if self._pending else 0.0)
                self._pending.append((at, left, right))

    def lighthouse_fix(self) -> Pose | None:
        """What the Lighthouse reports: the pose plus noise, or None during a dropout or a blackout."""
        with self._lock:
            self._advance()
            s = self._s
            d = self.disturbance
            if self.lighthouse_blackout or (d is not None and not d.fix_available(s.t - self._t0)):
                return None
            nx, ny, nyaw = (0.0, 0.0, 0.0) if d is None else d.fix_noise()
            ox, oy = (0.0, 0.0) if d is None else d.cfg.lighthouse_offset_m
            return Pose(s.x + nx + ox, s.y + ny + oy, wrap_angle(s.yaw + nyaw))

    def toggle_lighthouse_blackout(self) -> None:
        self.lighthouse_blackout = not self.lighthouse_blackout

    def current_velocity(self) -> tuple[float, float]:
        """The water current (m/s, world frame) acting on the robot now."""
        with self._lock:
            d = self.disturbance
            return (0.0, 0.0) if d is None else d.current(self.clock() - self._t0)

    def pose(self) -> Pose:
        with self._lock:
            self._advance()
            return Pose(self._s.x, self._s.y, self._s.yaw)

    def wheel_speeds(self) -> tuple[float, float]:
        """Current (left, right) wheel linear speeds, m/s."""
        with self._lock:
            self._advance()
            return (self._s.v_left, self._s.v_right)

    def imu(self) -> tuple[list[float], list[float]]:
        """(accel m/s^2, gyro rad/s) in the body frame (x forward, y left, z up); accel includes +g."""
        with self._lock:
            self._advance()
            s = self._s
            v = (s.v_left + s.v_right) / 2
            w = (s.v_right - s.v_left) / self.wheel_base_m
            return [s.accel_fwd, v * w, GRAVITY], [0.0, 0.0, w]

    def teleport(self, pose: Pose) -> None:
        with self._lock:
            self._advance()
            self._s.x, self._s.y, self._s.yaw = pose.x, pose.y, wrap_angle(pose.yaw)
