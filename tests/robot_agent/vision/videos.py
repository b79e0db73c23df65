"""Test videos made on the fly (cv2.VideoWriter) from the simulated camera."""

from __future__ import annotations

import math
from pathlib import Path

import cv2

from robot_agent.vision.settings import CaptureSettings
from robot_agent.vision.sim_camera import SimCamera, TagPlacement


def write_video(path: Path, tag_ids: list[int]) -> None:
    """A short MJPG video: one frame per tag id, each showing that tag."""
    cam = SimCamera(CaptureSettings())
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (640, 480))
    assert writer.isOpened()
    for tag_id in tag_ids:
        tag = TagPlacement.facing(tag_id, 0.15, 0.6, 0.0, 0.1, math.pi + 0.5)
        writer.write(cam.render((0.0, 0.0, 0.0), [tag]))
    writer.release()
