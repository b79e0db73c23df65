"""Capture settings shared by the camera and apriltag plugins (pure pydantic: no numpy/cv2 here).

Both plugin configs carry these fields so either may be configured alone; when both are configured the
fields each sets explicitly are merged into one capture (a field set to different values in the two is a
config error), because the two plugins share one camera.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

SourceKind = Literal["auto", "sim", "picamera2", "opencv"]


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """Pinhole camera parameters in pixels (the AprilTag detector's ``camera_params``)."""

    fx: float
    fy: float
    cx: float
    cy: float

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.fx, self.fy, self.cx, self.cy)

    def scaled(self, sx: float, sy: float) -> Intrinsics:
        """The same camera at another resolution (same field of view)."""
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy)

    def as_dict(self) -> dict[str, float]:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}

    @classmethod
    def parse(cls, text: str) -> Intrinsics:
        """``"FX,FY,CX,CY"`` (the CLI's ``--camera``)."""
        parts = [p.strip() for p in text.split(",")]
        if len(parts) != 4:
            raise ValueError(f"expected FX,FY,CX,CY, got {text!r}")
        fx, fy, cx, cy = (float(p) for p in parts)
        if fx <= 0 or fy <= 0:
            raise ValueError("fx and fy must be positive")
        return cls(fx, fy, cx, cy)


class CaptureSettings(BaseModel):
    """Where frames come from and the camera's geometry."""

    model_config = ConfigDict(extra="forbid")

    #: ``auto``: the simulated camera when the agent simulates, else Picamera2, else OpenCV.
    source: SourceKind = "auto"
    #: OpenCV source: a camera index (``0``) or a video file path (looped).
    device: int | str = 0
    width: int = Field(default=640, gt=0, le=8192)
    height: int = Field(default=480, gt=0, le=8192)
    #: Capture rate; the plugins publish at most this often.
    fps: float = Field(default=10.0, gt=0.0, le=240.0)
    fx: float = Field(default=500.0, gt=0.0)
    fy: float = Field(default=500.0, gt=0.0)
    #: Principal point; ``None`` = the image centre.
    cx: float | None = None
    cy: float | None = None
    #: OpenCV distortion coefficients (k1, k2, p1, p2[, k3...]) from ``fleet-agent calibrate``; empty = none.
    dist_coeffs: list[float] = Field(default_factory=list, max_length=14)
    # Simulated camera mount on the robot (metres / degrees; pitch > 0 tilts the camera up).
    mount_height_m: float = 0.10
    mount_forward_m: float = 0.0
    mount_pitch_deg: float = Field(default=0.0, ge=-89.0, le=89.0)
    #: Simulated sensor noise (grey-level standard deviation); 0 keeps frames deterministic.
    sim_noise: float = Field(default=0.0, ge=0.0, le=50.0)

    def intrinsics(self) -> Intrinsics:
        cx = self.width / 2.0 if self.cx is None else self.cx
        cy = self.height / 2.0 if self.cy is None else self.cy
        return Intrinsics(self.fx, self.fy, cx, cy)


CAPTURE_FIELDS: frozenset[str] = frozenset(CaptureSettings.model_fields)


def explicit_capture_fields(config: BaseModel) -> dict[str, object]:
    """The capture fields a plugin config sets explicitly (the rest are defaults and never conflict)."""
    return {name: getattr(config, name) for name in sorted(config.model_fields_set & CAPTURE_FIELDS)}
