"""Chessboard camera calibration (replaces the seed's script and its 0.9 fudge factor).

``calibrate`` runs OpenCV's findChessboardCorners + cornerSubPix + calibrateCamera and reports the
intrinsics and the RMS reprojection error; ``write_camera_config`` puts them into the agent's TOML config
(every ``[[sensors]]`` entry of type camera or apriltag, since both share the capture), leaving the rest
of the file as it was.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

_CAMERA_TYPES = ("camera", "apriltag")


class CalibrationError(RuntimeError):
    pass


@dataclass
class CalibrationResult:
    fx: float
    fy: float
    cx: float
    cy: float
    dist_coeffs: list[float]
    rms_px: float
    width: int
    height: int
    images_used: list[str] = field(default_factory=list)
    images_rejected: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "dist_coeffs": self.dist_coeffs,
            "rms_px": self.rms_px,
            "width": self.width,
            "height": self.height,
            "images_used": self.images_used,
            "images_rejected": self.images_rejected,
        }

    def config_values(self) -> dict[str, Any]:
        """The capture settings this calibration fixes (intrinsics hold for this resolution only)."""
        return {
            "width": self.width,
            "height": self.height,
            "fx": round(self.fx, 3),
            "fy": round(self.fy, 3),
            "cx": round(self.cx, 3),
            "cy": round(self.cy, 3),
            "dist_coeffs": [round(v, 6) for v in self.dist_coeffs],
        }


def parse_board(text: str) -> tuple[int, int]:
    """``"9x6"`` → (9, 6): inner corners per row and per column (OpenCV's pattern size)."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise ValueError(f"board must be COLSxROWS of inner corners, e.g. 9x6; got {text!r}")
    cols, rows = int(m.group(1)), int(m.group(2))
    if cols < 2 or rows < 2:
        raise ValueError("a board needs at least 2x2 inner corners")
    return cols, rows


def find_corners(gray: npt.NDArray[Any], board: tuple[int, int]) -> npt.NDArray[Any] | None:
    import cv2

    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, board, flags=flags)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    return cv2.cornerSubPix(gray, corners, (7, 7), (-1, -1), criteria)


def calibrate(
    images: Sequence[tuple[str, npt.NDArray[Any]]], board: tuple[int, int], square_mm: float
) -> CalibrationResult:
    """Calibrate from (name, image) pairs; images where the board is not found are skipped."""
    import cv2

    if square_mm <= 0:
        raise CalibrationError("square size must be positive")
    cols, rows = board
    obj = np.zeros((cols * rows, 3), np.float32)
    obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * (square_mm / 1000.0)
    obj_pts: list[npt.NDArray[Any]] = []
    img_pts: list[npt.NDArray[Any]] = []
    used: list[str] = []
    rejected: list[str] = []
    size: tuple[int, int] | None = None
    for name, image in images:
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        this_size = (int(gray.shape[1]), int(gray.shape[0]))
        if size is None:
            size = this_size
        elif this_size != size:
            raise CalibrationError(f"{name}: size {this_size} differs from the first image's {size}")
        corners = find_corners(gray, board)
        if corners is None:
            rejected.append(name)
            continue
        obj_pts.append(obj)
        img_pts.append(corners)
        used.append(name)
    if size is None or len(used) < 3:
        raise CalibrationError(
            f"the {cols}x{rows} board was found in {len(used)} image(s); at least 3 views are needed "
            "(check --board: it counts inner corners)"
        )
    rms, k, dist, _, _ = cv2.calibrateCamera(obj_pts, img_pts, size, None, None)
    if not math.isfinite(rms):
        raise CalibrationError("calibration did not converge")
    return CalibrationResult(
        fx=float(k[0, 0]),
        fy=float(k[1, 1]),
        cx=float(k[0, 2]),
        cy=float(k[1, 2]),
        dist_coeffs=[float(v) for v in np.asarray(dist).ravel()],
        rms_px=float(rms),
        width=size[0],
        height=size[1],
        images_used=used,
        images_rejected=rejected,
    )


# --------------------------------------------------------------------------------------------------
# Writing the agent config (a small, careful text edit: tomllib cannot write, and comments must stay).
# --------------------------------------------------------------------------------------------------

_HEADER_RE = re.compile(r"^\s*\[")
_SENSORS_RE = re.compile(r"^\s*\[\[\s*sensors\s*\]\]\s*(#.*)?$")
_TYPE_RE = re.compile(r"""^\s*type\s*=\s*["']([^"']*)["']""")


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"unsupported TOML value {v!r}")


def write_camera_config(path: Path, values: dict[str, Any]) -> list[str]:
    """Set ``values`` in every camera/apriltag ``[[sensors]]`` entry of the TOML file (created or appended
    as a camera entry when there is none). Returns the sensor types updated."""
    text = path.read_text() if path.exists() else ""
    if text:
        tomllib.loads(text)  # refuse to edit a file that is not valid TOML
    lines = text.splitlines()
    # Locate the [[sensors]] blocks: header line index and end (next table header or EOF).
    blocks: list[tuple[int, int, str]] = []
    for i, line in enumerate(lines):
        if _SENSORS_RE.match(line):
            end = next((j for j in range(i + 1, len(lines)) if _HEADER_RE.match(lines[j])), len(lines))
            kind = next((m.group(1) for j in range(i + 1, end) if (m := _TYPE_RE.match(lines[j]))), "")
            blocks.append((i, end, kind))
    updated: list[str] = []
    for start, end, kind in reversed(blocks):  # bottom-up keeps earlier indices valid
        if kind not in _CAMERA_TYPES:
            continue
        body = lines[start + 1 : end]
        for key, value in values.items():
            key_re = re.compile(rf"^\s*{re.escape(key)}\s*=")
            new_line = f"{key} = {_toml_value(value)}"
            idx = next((j for j, ln in enumerate(body) if key_re.match(ln)), None)
            if idx is not None:
                body[idx] = new_line
            else:
                # after the last key line, before trailing blank/comment lines
                last = max(
                    (j for j, ln in enumerate(body) if ln.strip() and not ln.lstrip().startswith("#")),
                    default=-1,
                )
                body.insert(last + 1, new_line)
        lines[start + 1 : end] = body
        updated.append(kind)
    if not updated:
        if lines and lines[-1].strip():
            lines.append("")
        lines.append("[[sensors]]")
        lines.append('type = "camera"')
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in values.items())
        updated.append("camera")
    new_text = "\n".join(lines) + "\n"
    parsed = tomllib.loads(new_text)  # the edit must leave valid TOML with the values in place
    for entry in parsed.get("sensors", []):
        if entry.get("type") in _CAMERA_TYPES:
            for k, v in values.items():
                if entry.get(k) != v:
                    raise CalibrationError(f"could not write {k} into {path} (unusual layout?)")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(new_text)
    tmp.replace(path)
    return sorted(updated)
