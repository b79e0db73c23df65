"""Camera relay: keeps the latest frame of each robot and hands it to live viewers, newest wins.

Frames arrive as ``fleet/{id}/camera`` binary payloads (QoS 0). A viewer that is slower than the camera
never builds a backlog: each viewer holds one slot, a new frame replaces an unsent one (counted as
dropped), so the age of what the browser shows stays one frame at most behind the robot.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from fleet_protocol import CameraHeader, decode_camera_frame


@dataclass(slots=True)
class Frame:
    robot_id: str
    header: CameraHeader
    jpeg: bytes
    #: The frame exactly as the robot sent it (MFC1 header + JPEG): what viewers receive.
    payload: bytes
    received: float


class CameraViewer:
    """One live viewer of one robot's camera: a single-frame slot plus a wake-up event."""

    def __init__(self, robot_id: str) -> None:
        self.robot_id = robot_id
        self._slot: Frame | None = None
        self._wake = asyncio.Event()
        self.sent = 0
        self.dropped = 0

    def offer(self, frame: Frame) -> None:
        if self._slot is not None:
            self.dropped += 1
        self._slot = frame
        self._wake.set()

    async def next_frame(self) -> Frame:
        while self._slot is None:
            self._wake.clear()
            await self._wake.wait()
        frame, self._slot = self._slot, None
        self.sent += 1
        return frame


@dataclass
class _RobotCamera:
    latest: Frame | None = None
    frames: int = 0
    #: receive times of recent frames, for the rate shown in the UI
    recent: list[float] = field(default_factory=list)


class CameraRelay:
    def __init__(self, *, recorder: Callable[[Frame], None] | None = None) -> None:
        #: runs keep frames through this (runs/recorder.py); called on the event loop, must not block
        self._recorder = recorder
        self._robots: dict[str, _RobotCamera] = {}
        self._viewers: dict[str, set[CameraViewer]] = {}
        self.frames_in = 0
        self.bytes_in = 0

    def on_frame(self, robot_id: str, payload: bytes, received: float) -> None:
        """Validate (raises ProtocolError for a bad frame) and fan out to this robot's viewers."""
        header, jpeg = decode_camera_frame(payload)
        frame = Frame(robot_id, header, jpeg, payload, received)
        cam = self._robots.setdefault(robot_id, _RobotCamera())
        cam.latest = frame
        cam.frames += 1
        cam.recent.append(received)
        if len(cam.recent) > 30:
            del cam.recent[:-30]
        self.frames_in += 1
        self.bytes_in += len(payload)
        for viewer in self._viewers.get(robot_id, ()):
            viewer.offer(frame)
        if self._recorder is not None:
            self._recorder(frame)

    def latest(self, robot_id: str) -> Frame | None:
        cam = self._robots.get(robot_id)
        return cam.latest if cam else None

    def fps(self, robot_id: str, now: float | None = None) -> float:
        cam = self._robots.get(robot_id)
        if cam is None or len(cam.recent) < 2:
            return 0.0
        now = time.time() if now is None else now
        if now - cam.recent[-1] > 2.0:
            return 0.0
        return (len(cam.recent) - 1) / max(cam.recent[-1] - cam.recent[0], 1e-6)

    def add_viewer(self, robot_id: str) -> CameraViewer:
        viewer = CameraViewer(robot_id)
        self._viewers.setdefault(robot_id, set()).add(viewer)
        latest = self.latest(robot_id)
        if latest is not None:
            viewer.offer(latest)
        return viewer

    def remove_viewer(self, viewer: CameraViewer) -> None:
        viewers = self._viewers.get(viewer.robot_id)
        if viewers is not None:
            viewers.discard(viewer)
            if not viewers:
                del self._viewers[viewer.robot_id]

    def stats(self) -> dict[str, int]:
        viewers = [v for vs in self._viewers.values() for v in vs]
        return {
            "frames_in": self.frames_in,
            "bytes_in": self.bytes_in,
            "viewers": len(viewers),
            "viewer_frames_dropped": sum(v.dropped for v in viewers),
        }
