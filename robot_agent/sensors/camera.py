"""Camera sensor: JPEG frames of the shared capture as binary payloads on ``fleet/{id}/camera`` (QoS 0).

Each payload carries the capture's ``frame_seq`` (see :func:`fleet_protocol.encode_camera_frame`), the
same number the apriltag stream reports, so a viewer can overlay detections on the right frame. JPEG
encoding runs in a worker thread; OpenCV is imported in :meth:`CameraPlugin.start` only.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from pydantic import Field

from fleet_protocol import MAX_CAMERA_PAYLOAD_BYTES, CameraHeader, encode_camera_frame
from robot_agent.sensors.base import SensorConfig, SensorContext, SensorPlugin
from robot_agent.vision.settings import CaptureSettings, explicit_capture_fields

log = logging.getLogger(__name__)


class CameraConfig(SensorConfig, CaptureSettings):
    """``[[sensors]] type = "camera"``: stream options plus the shared capture's settings."""

    type: str = "camera"
    #: Frames published per second (at most the capture's ``fps``).
    rate_hz: float = Field(default=10.0, gt=0.0, le=60.0)
    jpeg_quality: int = Field(default=80, ge=10, le=100)
    #: Scale published frames to this size; ``None`` = the capture size.
    stream_width: int | None = Field(default=None, gt=0, le=8192)
    stream_height: int | None = Field(default=None, gt=0, le=8192)


def encode_jpeg(image: Any, quality: int, size: tuple[int, int] | None) -> tuple[bytes, int, int]:
    """JPEG bytes and their (width, height); ``size`` rescales first."""
    import cv2

    if size is not None and (image.shape[1], image.shape[0]) != size:
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes(), int(image.shape[1]), int(image.shape[0])


class CameraPlugin(SensorPlugin):
    type_name = "camera"
    default_stream = "camera"
    config_model = CameraConfig
    payload_model = CameraHeader

    def __init__(self, config: SensorConfig, ctx: SensorContext) -> None:
        super().__init__(config, ctx)
        assert isinstance(config, CameraConfig)
        self.cfg: CameraConfig = config
        self._capture: Any = None
        self._owner = f"camera:{self.stream}"
        self.frames_sent = 0
        self.frames_oversize = 0

    async def start(self) -> None:
        from robot_agent.vision.sources import SharedCapture

        self._capture = SharedCapture.of(self.ctx.shared, self.ctx.world)
        await self._capture.attach(self._owner, explicit_capture_fields(self.cfg))

    async def stop(self) -> None:
        cap, self._capture = self._capture, None
        if cap is not None:
            await cap.detach(self._owner)

    def _out_size(self, width: int, height: int) -> tuple[int, int] | None:
        w, h = self.cfg.stream_width, self.cfg.stream_height
        if w is None and h is None:
            return None
        if w is None:
            w = max(1, round(width * h / height))  # type: ignore[operator]
        if h is None:
            h = max(1, round(height * w / width))
        return (w, h)

    async def run(self) -> None:
        if self._capture is None:
            raise RuntimeError("camera plugin not started")
        loop = asyncio.get_running_loop()
        period = 1.0 / self.cfg.rate_hz
        last_seq = 0
        while True:
            t0 = loop.time()
            frame = await self._capture.next_frame(last_seq)
            last_seq = frame.seq
            size = self._out_size(*frame.size)
            jpeg, w, h = await asyncio.to_thread(encode_jpeg, frame.image, self.cfg.jpeg_quality, size)
            payload = encode_camera_frame(CameraHeader(frame_seq=frame.seq, ts=frame.ts, width=w, height=h), jpeg)
            if len(payload) > MAX_CAMERA_PAYLOAD_BYTES:
                self.frames_oversize += 1
                if self.frames_oversize in (1, 10, 100) or self.frames_oversize % 1000 == 0:
                    log.warning(
                        "camera frame %d too large (%d bytes): lower jpeg_quality or size",
                        frame.seq,
                        len(payload),
                    )
            else:
                self.ctx.emit_camera(self.stream, payload)
                self.frames_sent += 1
            delay = period - (loop.time() - t0)
            if delay > 0:
                await asyncio.sleep(delay)
