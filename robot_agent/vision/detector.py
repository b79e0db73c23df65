"""dt-apriltags wrapper producing the ``apriltag`` stream's detection objects (seed units: mm, degrees).

The Euler angles are the seed's ``TagFinder.get_Euler`` convention: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)
applied to dt-apriltags' ``pose_R`` (a tag seen upright and head-on reads roll 0, pitch 0, yaw 180).
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from robot_agent.vision.settings import Intrinsics


def euler_deg(r: npt.ArrayLike) -> dict[str, float]:
    """Roll, pitch, yaw in degrees of a rotation matrix (ZYX; gimbal-lock safe)."""
    m = np.asarray(r, dtype=np.float64)
    sy = math.hypot(m[0, 0], m[1, 0])
    if sy > 1e-6:
        roll = math.atan2(m[2, 1], m[2, 2])
        pitch = math.atan2(-m[2, 0], sy)
        yaw = math.atan2(m[1, 0], m[0, 0])
    else:
        roll = math.atan2(-m[1, 2], m[1, 1])
        pitch = math.atan2(-m[2, 0], sy)
        yaw = 0.0
    return {"roll": math.degrees(roll), "pitch": math.degrees(pitch), "yaw": math.degrees(yaw)}


def _r(v: float, nd: int) -> float:
    return round(float(v), nd)


class TagDetector:
    """One dt-apriltags ``Detector`` plus pose scaling per tag size. Not thread-safe: use from one thread."""

    def __init__(
        self,
        family: str = "tag36h11",
        tag_size_m: float = 0.1,
        nthreads: int | None = None,
        quad_decimate: float = 2.0,
        quad_sigma: float = 0.0,
        refine_edges: bool = True,
        decode_sharpening: float = 0.25,
        tag_sizes: Mapping[int, float] | None = None,
        dist_coeffs: list[float] | None = None,
    ) -> None:
        self._detector: Any = None  # before anything can fail: __del__ calls close()
        self._lock = threading.Lock()  # close() must never free the detector under a running detect()
        from dt_apriltags import Detector

        self.family = family
        self.tag_size_m = tag_size_m
        self.tag_sizes = dict(tag_sizes or {})
        self.dist_coeffs = list(dist_coeffs or [])
        self._undistort_key: tuple[Any, ...] | None = None
        self._maps: tuple[Any, Any] | None = None
        self._detector = Detector(
            families=family,
            nthreads=nthreads or os.cpu_count() or 1,
            quad_decimate=quad_decimate,
            quad_sigma=quad_sigma,
            refine_edges=int(refine_edges),
            decode_sharpening=decode_sharpening,
            debug=0,
        )
        params = self._detector.tag_detector_ptr.contents
        params.decode_sharpening = float(decode_sharpening)  # dt-apriltags truncates it to an int (0)
        if params.nthreads > 1:
            self._warm_up()

    def close(self) -> None:
        """Free the C detector in the right order.

        dt-apriltags' own ``__del__`` frees the tag families first and then destroys the detector, which
        still walks those families (a use-after-free that corrupts the heap and crashes the process
        later, e.g. when the apriltag plugin is restarted). Here the families are detached from the
        detector first, then freed, then the detector; the wrapper's ``__del__`` is left nothing to do.
        """
        with self._lock:
            det, self._detector = self._detector, None
            if det is not None and det.tag_detector_ptr is not None:
                self._destroy(det)

    @staticmethod
    def _destroy(det: Any) -> None:
        lib, ptr = det.libc, det.tag_detector_ptr
        det.tag_detector_ptr = None
        lib.apriltag_detector_clear_families.restype = None
        lib.apriltag_detector_clear_families(ptr)
        for name, fam in det.tag_families.items():
            destroy = getattr(lib, f"{name}_destroy")
            destroy.restype = None
            destroy(fam)
        det.tag_families = {}
        lib.apriltag_detector_destroy.restype = None
        lib.apriltag_detector_destroy(ptr)

    def __del__(self) -> None:
        if hasattr(self, "_lock"):
            self.close()

    def _warm_up(self) -> None:
        """Start the detector's worker threads safely.

        The libapriltag bundled with dt-apriltags creates its worker threads inside the first ``detect``
        and can hand out work before they all wait for it: a startup race that crashes the process,
        mostly when that first image is small (reproduced with 160x120 frames and 2 threads). Running
        the first detection on a large blurred image delays the first hand-out well past thread start;
        later runs are unaffected (every thread is then waiting).
        """
        params = self._detector.tag_detector_ptr.contents
        decimate, sigma = params.quad_decimate, params.quad_sigma
        params.quad_decimate, params.quad_sigma = 1.0, 1.5
        try:
            self._detector.detect(np.zeros((720, 960), np.uint8))
        finally:
            params.quad_decimate, params.quad_sigma = decimate, sigma

    def _undistort(self, gray: npt.NDArray[Any], cam: Intrinsics) -> npt.NDArray[Any]:
        """Remove lens distortion (maps cached per size and intrinsics) so the pinhole pose is right."""
        h, w = gray.shape[:2]
        key = (w, h, cam.as_tuple(), tuple(self.dist_coeffs))
        if self._undistort_key != key:
            k = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]], dtype=np.float64)
            d = np.asarray(self.dist_coeffs, dtype=np.float64)
            self._maps = cv2.initUndistortRectifyMap(k, d, None, k, (w, h), cv2.CV_16SC2)
            self._undistort_key = key
        assert self._maps is not None
        return cv2.remap(gray, self._maps[0], self._maps[1], cv2.INTER_LINEAR)

    def detect(self, image: npt.NDArray[Any], camera: Intrinsics) -> list[dict[str, Any]]:
        """Detections in the ``apriltag`` stream schema for one BGR or grayscale image."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if any(self.dist_coeffs):
            gray = self._undistort(gray, camera)
        gray = np.ascontiguousarray(gray, dtype=np.uint8)
        with self._lock:
            if self._detector is None:
                raise RuntimeError("detector closed")
            results = self._detector.detect(gray, True, camera.as_tuple(), self.tag_size_m)
        out: list[dict[str, Any]] = []
        for det in results:
            scale = self.tag_sizes.get(int(det.tag_id), self.tag_size_m) / self.tag_size_m
            t_mm = np.asarray(det.pose_t, dtype=np.float64).reshape(3) * 1000.0 * scale
            rot = np.asarray(det.pose_R, dtype=np.float64)
            err = float(det.pose_err) * scale * scale
            if not (np.all(np.isfinite(t_mm)) and np.all(np.isfinite(rot))):
                continue
            fam = det.tag_family
            out.append(
                {
                    "tag_id": int(det.tag_id),
                    "family": fam.decode() if isinstance(fam, bytes) else str(fam),
                    "corners": [[_r(u, 2), _r(v, 2)] for u, v in np.asarray(det.corners)],
                    "center": [_r(det.center[0], 2), _r(det.center[1], 2)],
                    "translation_mm": [_r(v, 2) for v in t_mm],
                    "rotation": [[_r(v, 6) for v in row] for row in rot],
                    "euler_deg": {k: _r(v, 3) for k, v in euler_deg(rot).items()},
                    "decision_margin": _r(det.decision_margin, 3),
                    "pose_error": float(f"{err:.6g}") if math.isfinite(err) else 0.0,
                }
            )
        return out

    def message(self, image: npt.NDArray[Any], camera: Intrinsics, frame_seq: int) -> dict[str, Any]:
        """The whole ``apriltag`` stream message for one frame."""
        h, w = image.shape[:2]
        return {
            "frame_seq": int(frame_seq),
            "image_size": [int(w), int(h)],
            "camera": camera.as_dict(),
            "detections": self.detect(image, camera),
        }
