"""What makes the simulator honest: a drifting current, imperfect motors, a noisy Lighthouse and latency.

Each disturbance has a name (the ``[sim]`` table of the agent config, docs/autonomy.md "Simulator") and all
are off unless ``disturbances = true`` (``fleet-agent --simulate --disturbances``; ``make demo`` and the
control tests turn them on; ``--no-current`` keeps the rest and removes the water current).
Randomness comes from one seeded generator per robot, so a run can be repeated.
"""

from __future__ import annotations

import hashlib
import math
import random

from pydantic import BaseModel, ConfigDict, Field, model_validator


class SimDisturbances(BaseModel):
    """The ``[sim]`` config table. Defaults are the values the issue asks for; ``disturbances`` turns them on."""

    model_config = ConfigDict(extra="forbid")

    #: Master switch: off = the perfect simulator (plain ``--simulate``).
    disturbances: bool = False
    #: Water current: a drift of ``current_min_mps``..``current_max_mps`` whose speed and direction change
    #: slowly (periods of ``current_period_s`` and a little more).
    current: bool = True
    current_min_mps: float = Field(default=0.01, ge=0.0, le=1.0)
    current_max_mps: float = Field(default=0.03, ge=0.0, le=1.0)
    current_period_s: float = Field(default=120.0, gt=1.0, le=86400.0)
    #: A steady current towards this heading (radians, world frame) instead of a wandering one: for a test
    #: that pushes a robot at a wall. None = a random start direction that then swings slowly.
    current_direction_rad: float | None = Field(default=None, ge=-10.0, le=10.0)
    #: Motor asymmetry: one wheel this fraction faster than commanded, the other this much slower.
    motor_asymmetry: float = Field(default=0.05, ge=0.0, le=0.5)
    #: Actuator noise: each wheel's speed is off by a random fraction (sigma), redrawn every ``noise_period_s``.
    actuator_noise: float = Field(default=0.05, ge=0.0, le=0.5)
    noise_period_s: float = Field(default=0.1, gt=0.0, le=10.0)
    #: Actuation latency: a set-point reaches the wheels uniformly ``latency_min_s``..``latency_max_s`` later.
    latency_min_s: float = Field(default=0.02, ge=0.0, le=1.0)
    latency_max_s: float = Field(default=0.05, ge=0.0, le=1.0)
    #: Lighthouse position noise (sigma, metres) and heading noise (sigma, radians).
    position_noise_m: float = Field(default=0.005, ge=0.0, le=1.0)
    yaw_noise_rad: float = Field(default=0.01, ge=0.0, le=1.0)
    #: Lighthouse dropouts: on average this many a second, each lasting ``dropout_min_s``..``dropout_max_s``
    #: (brief: a robot stops and fails its goal after 0.3 s without a fix).
    dropout_rate_hz: float = Field(default=0.1, ge=0.0, le=100.0)
    dropout_min_s: float = Field(default=0.05, ge=0.0, le=60.0)
    dropout_max_s: float = Field(default=0.2, ge=0.0, le=60.0)
    #: A Lighthouse calibration error: every fix is off by this (x, y) in metres, whatever ``disturbances``
    #: says (a test of the ``localization_disagreement`` alarm: the AprilTags see the true pose).
    lighthouse_offset_m: tuple[float, float] = (0.0, 0.0)
    #: Seed of the random generator; None = derived from the robot id (repeatable per robot).
    seed: int | None = None

    @model_validator(mode="after")
    def _ranges(self) -> SimDisturbances:
        for lo, hi in (
            ("current_min_mps", "current_max_mps"),
            ("latency_min_s", "latency_max_s"),
            ("dropout_min_s", "dropout_max_s"),
        ):
            if getattr(self, lo) > getattr(self, hi):
                raise ValueError(f"{lo} must not exceed {hi}")
        return self


class Disturbance:
    """The disturbances of one simulated robot, sampled by :class:`robot_agent.sim.world.SimWorld`."""

    def __init__(self, cfg: SimDisturbances, robot_id: str = "") -> None:
        self.cfg = cfg
        seed = cfg.seed
        if seed is None:
            seed = int.from_bytes(hashlib.sha256(f"sim:{robot_id}".encode()).digest()[:8], "big")
        self.rng = random.Random(seed)
        on = cfg.disturbances
        # Which wheel is the stronger one, and where the current starts pointing, are per robot.
        sign = 1.0 if self.rng.random() < 0.5 else -1.0
        a = cfg.motor_asymmetry if on else 0.0
        self.wheel_gain = (1.0 + sign * a, 1.0 - sign * a)
        self._dir0 = self.rng.uniform(-math.pi, math.pi)
        self._phase = self.rng.uniform(0, 2 * math.pi)
        self.current_on = on and cfg.current and cfg.current_max_mps > 0
        self.noise_on = on and cfg.actuator_noise > 0
        self.latency_on = on and cfg.latency_max_s > 0
        self.fix_noise_on = on
        self.dropouts_on = on and cfg.dropout_rate_hz > 0
        self._noise = (0.0, 0.0)
        self._noise_until = -math.inf
        self._dropout_until = -math.inf
        self._next_dropout = math.inf
        self._last_fix_t: float | None = None

    # -- the water --------------------------------------------------------------------------------
    def current(self, t: float) -> tuple[float, float]:
        """Current velocity (m/s, world frame) at ``t`` seconds since the world started."""
        if not self.current_on:
            return (0.0, 0.0)
        c = self.cfg
        w = 2 * math.pi / c.current_period_s
        mid = (c.current_min_mps + c.current_max_mps) / 2
        half = (c.current_max_mps - c.current_min_mps) / 2
        speed = mid + half * math.sin(w * 0.73 * t + self._phase)
        if c.current_direction_rad is not None:
            heading = c.current_direction_rad
        else:
            heading = self._dir0 + 0.6 * math.sin(w * t) + 0.3 * math.sin(w * 2.3 * t + self._phase)
        return (speed * math.cos(heading), speed * math.sin(heading))

    # -- the motors -------------------------------------------------------------------------------
    def wheel_factors(self, t: float) -> tuple[float, float]:
        """Multipliers of the (left, right) set-points at ``t``: asymmetry times the current noise draw."""
        if self.noise_on and t >= self._noise_until:
            s = self.cfg.actuator_noise
            self._noise = (self.rng.gauss(0.0, s), self.rng.gauss(0.0, s))
            self._noise_until = t + self.cfg.noise_period_s
        return (self.wheel_gain[0] * (1.0 + self._noise[0]), self.wheel_gain[1] * (1.0 + self._noise[1]))

    def latency(self) -> float:
        if not self.latency_on:
            return 0.0
        return self.rng.uniform(self.cfg.latency_min_s, self.cfg.latency_max_s)

    # -- the Lighthouse ---------------------------------------------------------------------------
    def fix_available(self, t: float) -> bool:
        """False during a dropout. Dropouts start as a Poisson process of ``dropout_rate_hz``."""
        if not self.dropouts_on:
            return True
        if self._next_dropout == math.inf:
            self._next_dropout = t + self.rng.expovariate(self.cfg.dropout_rate_hz)
        if t >= self._next_dropout:
            self._dropout_until = self._next_dropout + self.rng.uniform(self.cfg.dropout_min_s, self.cfg.dropout_max_s)
            self._next_dropout = self._dropout_until + self.rng.expovariate(self.cfg.dropout_rate_hz)
        return t >= self._dropout_until

    def fix_noise(self) -> tuple[float, float, float]:
        if not self.fix_noise_on:
            return (0.0, 0.0, 0.0)
        c = self.cfg
        return (
            self.rng.gauss(0.0, c.position_noise_m),
            self.rng.gauss(0.0, c.position_noise_m),
            self.rng.gauss(0.0, c.yaw_noise_rad),
        )
