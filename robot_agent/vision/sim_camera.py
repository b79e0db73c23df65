"""The simulated camera: renders real tag36h11 AprilTags placed in the world into the robot's view.

Tags are OpenCV's aruco ``DICT_APRILTAG_36h11`` markers (bit-identical to the AprilTag family), each drawn
on a white border and projected with a pinhole model from the robot's simulated pose, so the real detector
runs on them and the renderer can tell the exact pose each detection should report.

Frames (all right-handed, metres):
- world: x, y on the floor, z up; robot yaw counter-clockwise from +x; robot forward = (cos yaw, sin yaw).
- camera: x right, y down, z forward (= robot forward, tilted up by the mount pitch).
- tag: dt-apriltags' convention, measured against the detector: for a tag seen upright and head-on
  the pose rotation is diag(-1, -1, 1), i.e. tag x = the viewer's left, y = up, z = into the tag.
Pixel coordinates follow the AprilTag library (pixel (i, j) covers [i, i+1) x [j, j+1)).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from robot_agent.vision.settings import CaptureSettings, Intrinsics

FloatArray = npt.NDArray[np.float64]
Pose2D = tuple[float, float, float]

#: Tag edge (black square) in cells, and the texture with its one-cell white border.
_TAG_CELLS = 8
_TEX_CELLS = 10
_NEAR_M = 0.02
_TEXTURE_LEVELS = (2, 4, 8, 16, 32, 64)


@dataclass(frozen=True, slots=True)
class TagPlacement:
    """One tag in the world: ``position`` is its centre, ``rotation`` maps tag-frame vectors to world."""

    tag_id: int
    size_m: float
    position: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...]

    @classmethod
    def facing(cls, tag_id: int, size_m: float, x: float, y: float, z: float, yaw: float) -> TagPlacement:
        """An upright tag (e.g. on a wall) whose printed face looks towards heading ``yaw`` (radians)."""
        c, s = math.cos(yaw), math.sin(yaw)
        x_t = (s, -c, 0.0)  # the viewer's left
        y_t = (0.0, 0.0, 1.0)  # up
        z_t = (-c, -s, 0.0)  # into the tag
        rot = tuple((x_t[i], y_t[i], z_t[i]) for i in range(3))
        return cls(int(tag_id), float(size_m), (float(x), float(y), float(z)), rot)

    def rotation_matrix(self) -> FloatArray:
        return np.asarray(self.rotation, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class TagTruth:
    """What a perfect detector reports for one tag: pose in the camera frame and pixel corners."""

    tag_id: int
    rotation: FloatArray  # R_cam_tag
    translation: FloatArray  # metres, camera frame
    corners: FloatArray  # 4x2, dt-apriltags' corner order
    center: FloatArray  # projection of the tag centre
    in_view: bool  # whole black square inside the image and facing the camera

    @property
    def distance(self) -> float:
        return float(np.linalg.norm(self.translation))


def camera_pose(pose: Pose2D, settings: CaptureSettings) -> tuple[FloatArray, FloatArray]:
    """Camera centre in the world and R_world_cam (columns: camera x, y, z in world coordinates)."""
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    fwd = np.array([c, s, 0.0])
    right = np.array([s, -c, 0.0])
    down = np.array([0.0, 0.0, -1.0])
    p = math.radians(settings.mount_pitch_deg)
    fwd_t = math.cos(p) * fwd - math.sin(p) * down
    down_t = math.cos(p) * down + math.sin(p) * fwd
    centre = np.array([x, y, 0.0]) + settings.mount_forward_m * fwd + np.array([0.0, 0.0, settings.mount_height_m])
    return centre, np.column_stack([right, down_t, fwd_t])


def _tag_points(half: float) -> FloatArray:
    """Corners of a square of half-edge ``half`` in the tag frame, in dt-apriltags' corner order
    (image right-top, left-top, left-bottom, right-bottom for an upright tag)."""
    return np.array([[-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0], [-half, -half, 0.0]])


def _texture_points(half: float) -> FloatArray:
    """Tag-frame points of the texture's top-left, top-right, bottom-right, bottom-left corners."""
    return np.array([[half, half, 0.0], [-half, half, 0.0], [-half, -half, 0.0], [half, -half, 0.0]])


class SimCamera:
    """Pinhole renderer for one camera configuration. Not thread-safe (texture cache); one per capture."""

    def __init__(self, settings: CaptureSettings) -> None:
        self.settings = settings
        self.width = settings.width
        self.height = settings.height
        self.intrinsics: Intrinsics = settings.intrinsics()
        self._dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
        self._max_id = int(self._dictionary.bytesList.shape[0]) - 1
        self._textures: dict[tuple[int, int], npt.NDArray[Any]] = {}
        rows = np.linspace(165.0, 105.0, self.height, dtype=np.float32)  # lighter wall, darker floor
        cols = np.linspace(-6.0, 6.0, self.width, dtype=np.float32)
        self._background = np.clip(rows[:, None] + cols[None, :], 0, 255).astype(np.uint8)
        self._rng = np.random.default_rng(0)

    # -- geometry

    def _project(self, pts_cam: FloatArray) -> FloatArray:
        k = self.intrinsics
        z = pts_cam[:, 2]
        return np.column_stack([k.fx * pts_cam[:, 0] / z + k.cx, k.fy * pts_cam[:, 1] / z + k.cy])

    def truth(self, pose: Pose2D, tags: Sequence[TagPlacement]) -> list[TagTruth]:
        """Ground truth for every tag in front of the camera (``in_view`` says if it is fully visible)."""
        centre, r_wc = camera_pose(pose, self.settings)
        r_cw = r_wc.T
        out: list[TagTruth] = []
        for tag in tags:
            r_ct = r_cw @ tag.rotation_matrix()
            t = r_cw @ (np.asarray(tag.position, dtype=np.float64) - centre)
            pts = (r_ct @ _tag_points(tag.size_m / 2.0).T).T + t
            if np.any(pts[:, 2] < _NEAR_M):
                continue
            corners = self._project(pts)
            facing = float(t @ r_ct[:, 2]) > 0.0
            inside = bool(
                np.all(corners[:, 0] >= 1.0)
                and np.all(corners[:, 0] <= self.width - 1.0)
                and np.all(corners[:, 1] >= 1.0)
                and np.all(corners[:, 1] <= self.height - 1.0)
            )
            center = self._project(t.reshape(1, 3))[0]
            out.append(TagTruth(tag.tag_id, r_ct, t, corners, center, facing and inside))
        return out

    # -- rendering

    def _texture(self, tag_id: int, cell_px: int) -> npt.NDArray[Any]:
        """Two-channel texture (grey, alpha) of the tag with its white border, ``cell_px`` per cell."""
        key = (tag_id, cell_px)
        tex = self._textures.get(key)
        if tex is None:
            if len(self._textures) > 512:
                self._textures.clear()
            marker = cv2.aruco.generateImageMarker(self._dictionary, tag_id, _TAG_CELLS * cell_px)
            grey = cv2.copyMakeBorder(marker, cell_px, cell_px, cell_px, cell_px, cv2.BORDER_CONSTANT, value=255)
            tex = np.dstack([grey, np.full_like(grey, 255)])
            self._textures[key] = tex
        return tex

    def render(self, pose: Pose2D, tags: Sequence[TagPlacement]) -> npt.NDArray[Any]:
        """One BGR frame of the robot's view."""
        canvas = self._background.copy()
        centre, r_wc = camera_pose(pose, self.settings)
        r_cw = r_wc.T
        items: list[tuple[float, TagPlacement, FloatArray]] = []
        for tag in tags:
            if not 0 <= tag.tag_id <= self._max_id or tag.size_m <= 0:
                continue
            r_ct = r_cw @ tag.rotation_matrix()
            t = r_cw @ (np.asarray(tag.position, dtype=np.float64) - centre)
            if float(t @ r_ct[:, 2]) <= 0.0:  # seen from behind: the back of the tag is blank
                continue
            half = tag.size_m / 2.0 * _TEX_CELLS / _TAG_CELLS
            pts = (r_ct @ _texture_points(half).T).T + t
            if np.any(pts[:, 2] < _NEAR_M):
                continue
            items.append((float(t[2]), tag, self._project(pts)))
        for _, tag, quad in sorted(items, key=lambda it: -it[0]):  # far to near: nearer tags occlude
            self._draw(canvas, tag.tag_id, quad)
        if self.settings.sim_noise > 0:
            noise = self._rng.normal(0.0, self.settings.sim_noise, canvas.shape)
            canvas = np.clip(canvas + noise, 0, 255).astype(np.uint8)
        return cv2.cvtColor(canvas, cv2.COLOR_GRAY2BGR)

    def _draw(self, canvas: npt.NDArray[Any], tag_id: int, quad: FloatArray) -> None:
        x0 = max(0, math.floor(float(quad[:, 0].min())))
        y0 = max(0, math.floor(float(quad[:, 1].min())))
        x1 = min(self.width, math.ceil(float(quad[:, 0].max())) + 1)
        y1 = min(self.height, math.ceil(float(quad[:, 1].max())) + 1)
        if x0 >= x1 or y0 >= y1:
            return
        edge = max(float(np.linalg.norm(quad[i] - quad[(i + 1) % 4])) for i in range(4))
        need = edge / _TEX_CELLS
        cell_px = next((n for n in _TEXTURE_LEVELS if n >= need), _TEXTURE_LEVELS[-1])
        tex = self._texture(tag_id, cell_px)
        size = float(tex.shape[0])
        # OpenCV puts pixel centres on integers: shift both sides by half a pixel.
        src = np.array([[0, 0], [size, 0], [size, size], [0, size]], dtype=np.float32) - 0.5
        dst = (quad - np.array([x0 + 0.5, y0 + 0.5])).astype(np.float32)
        h = cv2.getPerspectiveTransform(src, dst)
        warped = cv2.warpPerspective(
            tex, h, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
        )
        alpha = warped[:, :, 1].astype(np.float32) * (1.0 / 255.0)
        roi = canvas[y0:y1, x0:x1].astype(np.float32)
        roi += (warped[:, :, 0].astype(np.float32) - roi) * alpha
        canvas[y0:y1, x0:x1] = np.clip(roi + 0.5, 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------------------------------
# Scene: where the robot is and which tags exist. A small protocol so the renderer does not depend on
# the simulator's classes; :func:`scene_from_world` adapts the agent's SimWorld.
# --------------------------------------------------------------------------------------------------

PoseFn = Callable[[], Pose2D]
TagsFn = Callable[[], Sequence[TagPlacement]]


@dataclass(frozen=True, slots=True)
class Scene:
    pose: PoseFn
    tags: TagsFn


def static_scene(pose: Pose2D, tags: Sequence[TagPlacement]) -> Scene:
    fixed = list(tags)
    return Scene(lambda: pose, lambda: fixed)


def _attr(obj: Any, *names: str) -> Any:
    for name in names:
        if isinstance(obj, dict) and name in obj:
            return obj[name]
        if hasattr(obj, name):
            return getattr(obj, name)
    raise AttributeError(f"{type(obj).__name__} has none of {names}")


def placement_from(tag: Any) -> TagPlacement:
    """A :class:`TagPlacement` from the simulator's tag object (``SimTag``) or a plain dict."""
    if isinstance(tag, TagPlacement):
        return tag
    tag_id = int(_attr(tag, "id", "tag_id"))
    size = float(_attr(tag, "size_m", "size"))
    pos = _attr(tag, "position", "pos")
    x, y, z = (float(v) for v in pos)
    rot: Any
    try:
        rot = _attr(tag, "rotation", "yaw", "facing")
    except AttributeError:
        rot = 0.0
    if callable(rot):
        rot = rot()
    if isinstance(rot, int | float):
        return TagPlacement.facing(tag_id, size, x, y, z, float(rot))
    m = np.asarray(rot, dtype=np.float64)
    if m.shape != (3, 3):
        raise ValueError(f"tag {tag_id}: rotation must be a yaw or a 3x3 matrix")
    return TagPlacement(tag_id, size, (x, y, z), tuple((float(r[0]), float(r[1]), float(r[2])) for r in m))


def scene_from_world(world: Any) -> Scene:
    """Adapt the simulated world: its robot pose (x, y, yaw) and its ``tags`` list."""

    def pose() -> Pose2D:
        try:
            p = _attr(world, "pose", "get_pose", "robot_pose")
        except AttributeError:
            p = world  # x, y, yaw directly on the world
        if callable(p):
            p = p()
        if isinstance(p, tuple | list):
            return (float(p[0]), float(p[1]), float(p[2]))
        return (float(_attr(p, "x")), float(_attr(p, "y")), float(_attr(p, "yaw")))

    def tags() -> list[TagPlacement]:
        return [placement_from(t) for t in getattr(world, "tags", ())]

    return Scene(pose, tags)
