"""Differential-drive kinematics: body velocity (linear m/s, angular rad/s) <-> wheel set-points (-1..1).

The ``[kinematics]`` config table states the robot's geometry and limits. Every velocity the robot is asked
for (a ``drive``, or the goal controllers) goes through :meth:`Kinematics.mix`, which enforces the limits
and says what it changed, so the clamped values can be reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field


class KinematicsConfig(BaseModel):
    """``[kinematics]``. ``None`` = the top-level ``wheel_base_m`` / ``max_speed_mps`` settings."""

    model_config = ConfigDict(extra="forbid")

    #: Distance between the two wheels (or thrusters), metres.
    wheel_base_m: float | None = Field(default=None, gt=0.0, le=5.0)
    #: Speed of a wheel at set-point 1.0, m/s.
    max_wheel_speed_mps: float | None = Field(default=None, gt=0.0, le=10.0)
    #: Limits of the body velocity, whatever a command asks.
    max_linear_mps: float = Field(default=0.2, gt=0.0, le=10.0)
    max_angular_rps: float = Field(default=1.5, gt=0.0, le=50.0)
    #: Time from "stop" to standing still (latency + motor lag), used for the geofence's stopping distance.
    stop_time_s: float = Field(default=0.25, ge=0.0, le=10.0)


@dataclass(frozen=True, slots=True)
class WheelCommand:
    """Wheel set-points (fractions of full wheel speed) and the body velocity they really mean."""

    left: float
    right: float
    linear: float
    angular: float
    clamped: bool

    @property
    def stopped(self) -> bool:
        return self.left == 0.0 and self.right == 0.0


STOPPED = WheelCommand(0.0, 0.0, 0.0, 0.0, False)


@dataclass(frozen=True, slots=True)
class Kinematics:
    wheel_base_m: float
    max_wheel_speed_mps: float
    max_linear_mps: float
    max_angular_rps: float
    stop_time_s: float = 0.25

    @classmethod
    def from_config(cls, cfg: KinematicsConfig, wheel_base_m: float, max_speed_mps: float) -> Kinematics:
        wheel_max = cfg.max_wheel_speed_mps or max_speed_mps
        return cls(
            wheel_base_m=cfg.wheel_base_m or wheel_base_m,
            max_wheel_speed_mps=wheel_max,
            max_linear_mps=min(cfg.max_linear_mps, wheel_max),
            max_angular_rps=cfg.max_angular_rps,
            stop_time_s=cfg.stop_time_s,
        )

    def mix(self, linear: float, angular: float) -> WheelCommand:
        """Wheel set-points for a body velocity, within every limit. When the wheels cannot do both, the
        turn keeps priority (steering is what keeps a swimmer on its line) and the forward speed gives way.
        NaN or an infinity (a broken estimate) stops the wheels: min/max would pass NaN on to the motors."""
        if not (math.isfinite(linear) and math.isfinite(angular)):
            return WheelCommand(0.0, 0.0, 0.0, 0.0, True)
        lin = min(max(linear, -self.max_linear_mps), self.max_linear_mps)
        ang = min(max(angular, -self.max_angular_rps), self.max_angular_rps)
        half_turn = ang * self.wheel_base_m / 2
        wmax = self.max_wheel_speed_mps
        if abs(half_turn) > wmax:  # even turning in place exceeds a wheel: scale the turn down
            ang = math.copysign(wmax, ang) * 2 / self.wheel_base_m
            half_turn = math.copysign(wmax, half_turn)
        room = wmax - abs(half_turn)
        lin = min(max(lin, -room), room)
        left = (lin - half_turn) / wmax
        right = (lin + half_turn) / wmax
        clamped = not (math.isclose(lin, linear, abs_tol=1e-9) and math.isclose(ang, angular, abs_tol=1e-9))
        return WheelCommand(_unit(left), _unit(right), lin, ang, clamped)

    def body(self, left: float, right: float) -> tuple[float, float]:
        """(linear m/s, angular rad/s) of wheel set-points (fractions)."""
        vl, vr = left * self.max_wheel_speed_mps, right * self.max_wheel_speed_mps
        return (vl + vr) / 2, (vr - vl) / self.wheel_base_m


def _unit(v: float) -> float:
    return min(max(v, -1.0), 1.0)
