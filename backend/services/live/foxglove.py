"""Live to Foxglove / Lichtblick (optional, off by default: ``FLEET_FOXGLOVE_WS``): a Foxglove WebSocket
server (``foxglove-sdk``, the ``foxglove`` extra) that shows every robot's pose, camera and AprilTag
detections as they arrive, in the same well-known schemas and on the same topics as the MCAP export
(runs/mcap.py): ``/{robot}/position`` as ``foxglove.PoseInFrame`` in the ``pool`` frame,
``/{robot}/camera`` as ``foxglove.CompressedImage``, ``/{robot}/camera/annotations`` as
``foxglove.ImageAnnotations``. Log time is the robot's time stamp, as in the export.

Read-only: the server announces no capability (no client publishing, parameters or services), so a
connected app can only subscribe. It binds to 127.0.0.1 unless ``FLEET_FOXGLOVE_WS_HOST`` says otherwise,
and has no authentication of its own: docs/runs.md says how to expose it safely.

Called on the event loop (ingest and the camera relay); the SDK encodes and sends on its own threads, and
a channel nobody subscribed to costs a dictionary lookup.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from backend.services.live.camera import Frame

log = logging.getLogger(__name__)

#: the frame poses are in (the Lighthouse frame of the pool), as in the MCAP export
POOL_FRAME = "pool"


def _ns(ts: float) -> int:
    return max(0, round(ts * 1e9))


class FoxgloveLive:
    """One Foxglove WebSocket server and its channels (one per robot and kind, made when first needed)."""

    def __init__(self, *, host: str, port: int, name: str = "mollusca-fleet") -> None:
        # imported here: foxglove-sdk is an optional extra, needed only when the setting is on
        import foxglove
        from foxglove import channels, messages

        self._fg = foxglove
        self._ch = channels
        self._msg = messages
        self._context = foxglove.Context()  # our own: nothing else logged in this process reaches the app
        self.server = foxglove.start_server(name=name, host=host, port=port, capabilities=[], context=self._context)
        self.port: int = self.server.port
        self.host = host
        self._poses: dict[str, Any] = {}
        self._images: dict[str, Any] = {}
        self._annotations: dict[str, Any] = {}
        log.warning(
            "Foxglove WebSocket server on ws://%s:%d (read-only, no authentication of its own: docs/runs.md)",
            host,
            self.port,
        )

    def _timestamp(self, ts: float) -> Any:
        sec, nsec = divmod(_ns(ts), 1_000_000_000)
        return self._msg.Timestamp(sec, nsec)

    # -- what the server hears (event loop) -------------------------------------------------------------------
    def on_telemetry(self, robot_id: str, stream: str, ts: float, seq: int, data: dict[str, Any]) -> None:
        try:
            if stream == "position":
                self._pose(robot_id, ts, data)
            elif stream == "apriltag":
                self._detections(robot_id, ts, data)
        except Exception:  # a bad value must never stop ingest
            log.exception("foxglove: %s/%s not sent", robot_id, stream)

    def on_frame(self, frame: Frame) -> None:
        channel = self._images.get(frame.robot_id)
        if channel is None:
            channel = self._images[frame.robot_id] = self._ch.CompressedImageChannel(
                f"/{frame.robot_id}/camera", context=self._context
            )
        ts = frame.header.ts
        msg = self._msg.CompressedImage(
            timestamp=self._timestamp(ts), frame_id=f"{frame.robot_id}/camera", data=frame.jpeg, format="jpeg"
        )
        channel.log(msg, log_time=_ns(ts))

    def _pose(self, robot_id: str, ts: float, data: dict[str, Any]) -> None:
        channel = self._poses.get(robot_id)
        if channel is None:
            channel = self._poses[robot_id] = self._ch.PoseInFrameChannel(
                f"/{robot_id}/position", context=self._context
            )
        m = self._msg
        half_yaw = float(data.get("yaw") or 0.0) / 2
        pose = m.Pose(
            position=m.Vector3(
                x=float(data.get("x") or 0.0), y=float(data.get("y") or 0.0), z=float(data.get("z") or 0.0)
            ),
            orientation=m.Quaternion(x=0.0, y=0.0, z=math.sin(half_yaw), w=math.cos(half_yaw)),
        )
        channel.log(m.PoseInFrame(timestamp=self._timestamp(ts), frame_id=POOL_FRAME, pose=pose), log_time=_ns(ts))

    def _detections(self, robot_id: str, ts: float, data: dict[str, Any]) -> None:
        """Each tag's outline and id over the camera image, as the MCAP export draws them."""
        channel = self._annotations.get(robot_id)
        if channel is None:
            channel = self._annotations[robot_id] = self._ch.ImageAnnotationsChannel(
                f"/{robot_id}/camera/annotations", context=self._context
            )
        m = self._msg
        stamp = self._timestamp(ts)
        points, texts = [], []
        for det in data.get("detections") or []:
            corners = [m.Point2(x=float(u), y=float(v)) for u, v in det.get("corners") or []]
            points.append(
                m.PointsAnnotation(
                    timestamp=stamp,
                    type=m.PointsAnnotationType.LineLoop,
                    points=corners,
                    outline_color=m.Color(r=0.0, g=1.0, b=0.0, a=1.0),
                    thickness=2.0,
                )
            )
            cu, cv = det.get("center") or [0.0, 0.0]
            texts.append(
                m.TextAnnotation(
                    timestamp=stamp,
                    position=m.Point2(x=float(cu), y=float(cv)),
                    text=f"tag {det.get('tag_id')}",
                    font_size=14.0,
                    text_color=m.Color(r=1.0, g=1.0, b=1.0, a=1.0),
                )
            )
        channel.log(m.ImageAnnotations(timestamp=stamp, points=points, texts=texts), log_time=_ns(ts))

    def stop(self) -> None:
        self.server.stop()
