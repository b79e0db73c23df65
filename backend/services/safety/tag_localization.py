"""Where the AprilTags say the robot is: the camera's position in the site frame from one detection of a
mapped wall tag, for the ``localization_disagreement`` cross-check against the Lighthouse.

A detection gives the tag's pose in the camera frame (x right, y down, z forward; ``rotation`` R_cam_tag,
``translation_mm`` t): a point p in the tag frame is at R p + t in the camera's, so the camera centre is at
-R^T t in the tag frame. The tag map gives each tag's centre and the heading its printed face looks along
(``SiteTag.pose`` yaw); an upright wall tag's frame has x to the viewer's left, y up and z into the wall (as
the simulator and dt-apriltags place it), which takes that point into the site frame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from fleet_protocol.motion import SiteTag


def camera_xy_from_tag(
    tag: SiteTag, rotation: Sequence[Sequence[float]], translation_mm: Sequence[float]
) -> tuple[float, float]:
    """The camera centre (x, y metres, site frame) from one detection of ``tag``."""
    t = [v / 1000.0 for v in translation_mm]
    # camera centre in the tag frame: -R^T t
    c = [-sum(rotation[row][col] * t[row] for row in range(3)) for col in range(3)]
    yaw = float(tag.pose.get("yaw", 0.0))
    cos, sin = math.cos(yaw), math.sin(yaw)
    # tag axes in the site frame: x = viewer's left (sin, -cos, 0), y = up (0, 0, 1), z = into the wall (-cos, -sin, 0)
    x = float(tag.pose.get("x", 0.0)) + c[0] * sin - c[2] * cos
    y = float(tag.pose.get("y", 0.0)) - c[0] * cos - c[2] * sin
    return x, y


def robot_xy_from_tags(
    tags: Mapping[int, SiteTag], detections: Sequence[Mapping[str, Any]], yaw: float | None, camera_forward_m: float
) -> tuple[float, float, int] | None:
    """The robot's (x, y) by the mapped tags of one frame (their mean) and how many tags made it; None when no
    mapped tag is in the frame. ``camera_forward_m``: the camera sits that far ahead of the robot's centre
    (along the Lighthouse ``yaw``)."""
    xs: list[float] = []
    ys: list[float] = []
    for det in detections:
        tag_id = det.get("tag_id")
        tag = tags.get(tag_id) if isinstance(tag_id, int) else None
        if tag is None:
            continue
        try:
            cx, cy = camera_xy_from_tag(tag, det["rotation"], det["translation_mm"])
        except (KeyError, IndexError, TypeError, ValueError):
            continue
        if math.isfinite(cx) and math.isfinite(cy):
            xs.append(cx)
            ys.append(cy)
    if not xs:
        return None
    x, y = sum(xs) / len(xs), sum(ys) / len(ys)
    if camera_forward_m and yaw is not None:
        x -= camera_forward_m * math.cos(yaw)
        y -= camera_forward_m * math.sin(yaw)
    return x, y, len(xs)
