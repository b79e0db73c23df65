"""AprilTag sensor: detects tags in the shared camera's frames and publishes their poses (mm, degrees).

Detection runs in a worker thread (dt-apriltags releases the GIL), so the agent's event loop never
waits for it. numpy/OpenCV/dt-apriltags are imported in :meth:`AprilTagPlugin.start`, so merely
registering this plugin costs nothing on a robot without the ``vision`` extra.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from pydantic import Field

from fleet_protocol import AprilTagData
from robot_agent.sensors.base import SensorConfig, SensorContext, SensorPlugin
from robot_agent.vision.settings import CaptureSettings, explicit_capture_fields

log = logging.getLogger(__name__)


class AprilTagConfig(SensorConfig, CaptureSettings):
    """``[[sensors]] type = "apriltag"``: detector options plus (optionally) the shared capture's."""

    type: str = "apriltag"
    rate_hz: float = Field(default=10.0, gt=0.0, le=240.0)
    family: str = Field(default="tag36h11", pattern=r"^tag[A-Za-z0-9_]+$")
    #: Edge of the black square in metres (the seed's TAG_SIZE).
    tag_size_m: float = Field(default=0.1, gt=0.0, le=10.0)
    #: Per-tag sizes where they differ from ``tag_size_m`` (TOML: ``tag_sizes = {"3" = 0.2}``).
    tag_sizes: dict[int, float] = Field(default_factory=dict)
    #: Detector threads; ``None`` = all cores.
    nthreads: int | None = Field(default=None, ge=1, le=64)
    quad_decimate: float = Field(default=2.0, ge=1.0, le=8.0)
    quad_sigma: float = Field(default=0.0, ge=0.0, le=5.0)
    refine_edges: bool = True
    decode_sharpening: float = Field(default=0.25, ge=0.0, le=5.0)
    #: Publish frames without detections too, so a viewer knows the tags are gone.
    publish_empty: bool = True


class AprilTagPlugin(SensorPlugin):
    type_name = "apriltag"
    default_stream = "apriltag"
    config_model = AprilTagConfig
    payload_model = AprilTagData

    def __init__(self, config: SensorConfig, ctx: SensorContext) -> None:
        super().__init__(config, ctx)
        assert isinstance(config, AprilTagConfig)
        self.cfg: AprilTagConfig = config
        self._capture: Any = None
        self._detector: Any = None
        self._owner = f"apriltag:{self.stream}"
        self.frames_processed = 0

    async def start(self) -> None:
        from robot_agent.vision.detector import TagDetector
        from robot_agent.vision.sources import SharedCapture

        c = self.cfg
        # Building the decoder tables and starting the worker threads takes tens of ms: not on the loop.
        self._detector = await asyncio.to_thread(
            TagDetector,
            family=c.family,
            tag_size_m=c.tag_size_m,
            nthreads=c.nthreads,
            quad_decimate=c.quad_decimate,
            quad_sigma=c.quad_sigma,
            refine_edges=c.refine_edges,
            decode_sharpening=c.decode_sharpening,
            tag_sizes=c.tag_sizes,
        )
        self._capture = SharedCapture.of(self.ctx.shared, self.ctx.world)
        settings = await self._capture.attach(self._owner, explicit_capture_fields(c))
        self._detector.dist_coeffs = list(settings.dist_coeffs)

    async def stop(self) -> None:
        cap, self._capture = self._capture, None
        if cap is not None:
            await cap.detach(self._owner)
        det, self._detector = self._detector, None
        if det is not None:  # waits for a detection still running in its worker thread
            await asyncio.to_thread(det.close)

    async def run(self) -> None:
        if self._capture is None:
            raise RuntimeError("apriltag plugin not started")
        capture, detector = self._capture, self._detector
        loop = asyncio.get_running_loop()
        period = 1.0 / self.cfg.rate_hz
        last_seq = 0
        while True:
            t0 = loop.time()
            frame = await capture.next_frame(last_seq)
            last_seq = frame.seq
            msg = await asyncio.to_thread(detector.message, frame.image, frame.intrinsics, frame.seq)
            self.frames_processed += 1
            if msg["detections"] or self.cfg.publish_empty:
                self.ctx.emit(self.stream, msg)
            delay = period - (loop.time() - t0)
            if delay > 0:
                await asyncio.sleep(delay)
