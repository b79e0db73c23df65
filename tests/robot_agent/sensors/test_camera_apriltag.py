"""The camera and apriltag plugins together on one simulated capture, as the agent runs them."""

from __future__ import annotations

import asyncio
import math
import subprocess
import sys
import threading
from typing import Any

import cv2
import numpy as np
import pytest

from fleet_protocol import AprilTagData, decode_camera_frame
from robot_agent.sensors.apriltag import AprilTagConfig, AprilTagPlugin
from robot_agent.sensors.base import SensorContext
from robot_agent.sensors.camera import CameraConfig, CameraPlugin
from robot_agent.vision.detector import TagDetector
from robot_agent.vision.sim_camera import TagPlacement, static_scene
from robot_agent.vision.sources import CaptureConfigError, SourceError


class Recorder:
    def __init__(self) -> None:
        self.telemetry: list[tuple[str, dict[str, Any]]] = []
        self.camera: list[tuple[str, bytes]] = []

    def ctx(self, world: Any) -> SensorContext:
        return SensorContext(
            robot_id="r1",
            emit=lambda stream, data: self.telemetry.append((stream, data)),
            emit_retained=lambda stream, data: None,
            emit_camera=lambda stream, payload: self.camera.append((stream, payload)),
            world=world,
        )


TAGS = [
    TagPlacement.facing(11, 0.15, 1.0, 0.2, 0.1, math.pi - 0.6),
    TagPlacement.facing(12, 0.15, 1.4, -0.3, 0.15, math.pi + 0.6),
]


async def run_plugins(plugins: list[Any], until: Any, timeout: float = 8.0) -> None:
    for p in plugins:
        await p.start()
    tasks = [asyncio.create_task(p.run()) for p in plugins]
    try:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while not until():
            for t in tasks:
                if t.done():
                    t.result()  # surface a plugin crash
            assert loop.time() < deadline, "plugins produced too little"
            await asyncio.sleep(0.02)
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for p in plugins:
            await p.stop()


def capture_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "camera-capture"]


def test_camera_frames_and_detections_share_frame_seq() -> None:
    rec = Recorder()
    ctx = rec.ctx(static_scene((0.0, 0.0, 0.0), TAGS))
    camera = CameraPlugin(CameraConfig.model_validate({"type": "camera", "fps": 20, "rate_hz": 20}), ctx)
    apriltag = AprilTagPlugin(
        AprilTagConfig.model_validate({"type": "apriltag", "tag_size_m": 0.15, "nthreads": 1, "rate_hz": 20}),
        ctx,
    )

    def enough() -> bool:
        return len(rec.camera) >= 6 and len(rec.telemetry) >= 6

    asyncio.run(run_plugins([camera, apriltag], enough))
    assert capture_threads() == []
    assert ctx.shared["camera"].frames_captured >= 6  # one capture fed both

    frames: dict[int, np.ndarray] = {}
    for stream, payload in rec.camera:
        assert stream == "camera"
        header, jpeg = decode_camera_frame(payload)
        assert jpeg[:2] == b"\xff\xd8"
        img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (480, 640, 3) == (header.height, header.width, 3)
        frames[header.frame_seq] = img
    seqs = [decode_camera_frame(p)[0].frame_seq for _, p in rec.camera]
    assert seqs == sorted(set(seqs))  # increasing, never repeated

    messages = {}
    for stream, data in rec.telemetry:
        assert stream == "apriltag"
        msg = AprilTagData.model_validate(data)
        assert sorted(d.tag_id for d in msg.detections) == [11, 12]
        assert msg.image_size == [640, 480]
        assert msg.camera.model_dump() == {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0}
        messages[msg.frame_seq] = msg
    common = sorted(set(frames) & set(messages))
    assert common, "the browser must be able to match detections to frames"
    # The JPEG with that frame_seq shows the tags exactly where the detections say.
    det = TagDetector(tag_size_m=0.15, nthreads=1)
    from robot_agent.vision.settings import Intrinsics

    for seq in common[:3]:
        found = {d["tag_id"]: np.asarray(d["corners"]) for d in det.detect(frames[seq], Intrinsics(500, 500, 320, 240))}
        for d in messages[seq].detections:
            assert np.abs(found[d.tag_id] - np.asarray(d.corners)).max() < 1.5


def test_jpeg_quality_and_stream_size() -> None:
    rec = Recorder()
    ctx = rec.ctx(static_scene((0.0, 0.0, 0.0), TAGS))
    cfgs = [
        {"type": "camera", "fps": 30, "rate_hz": 30, "jpeg_quality": 30, "stream_width": 320},
    ]
    camera = CameraPlugin(CameraConfig.model_validate(cfgs[0]), ctx)
    asyncio.run(run_plugins([camera], lambda: len(rec.camera) >= 2))
    header, jpeg = decode_camera_frame(rec.camera[-1][1])
    assert (header.width, header.height) == (320, 240)
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (240, 320)
    assert len(jpeg) < 20_000  # a mostly grey frame at quality 30


def test_apriltag_alone_on_a_video_file(tmp_path: Any) -> None:
    """Without the camera plugin the apriltag plugin opens the capture itself (here: a video file)."""
    from tests.robot_agent.vision.videos import write_video

    path = tmp_path / "v.avi"
    write_video(path, [21, 22])
    rec = Recorder()
    ctx = rec.ctx(None)
    cfg = AprilTagConfig.model_validate(
        {
            "type": "apriltag",
            "source": "opencv",
            "device": str(path),
            "fps": 50,
            "rate_hz": 50,
            "tag_size_m": 0.15,
            "nthreads": 1,
        }
    )
    plugin = AprilTagPlugin(cfg, ctx)
    asyncio.run(run_plugins([plugin], lambda: len(rec.telemetry) >= 4))
    ids = {d["tag_id"] for _, m in rec.telemetry for d in m["detections"]}
    assert ids == {21, 22}
    assert capture_threads() == []


def test_missing_camera_fails_start_with_a_clear_error() -> None:
    rec = Recorder()
    ctx = rec.ctx(None)
    cam = CameraPlugin(
        CameraConfig.model_validate({"type": "camera", "source": "opencv", "device": "/no/such.avi"}), ctx
    )
    tag = AprilTagPlugin(AprilTagConfig.model_validate({"type": "apriltag", "source": "opencv", "device": 63}), ctx)

    async def main() -> None:
        with pytest.raises(SourceError, match=r"video file not found: /no/such\.avi"):
            await cam.start()
        await cam.stop()
        with pytest.raises(SourceError, match="cannot open camera index 63"):
            await tag.start()
        await tag.stop()

    asyncio.run(main())
    assert capture_threads() == []


def test_sim_source_without_world_fails_start() -> None:
    rec = Recorder()
    cam = CameraPlugin(CameraConfig.model_validate({"type": "camera", "source": "sim"}), rec.ctx(None))

    async def main() -> None:
        with pytest.raises(SourceError, match="simulated world"):
            await cam.start()
        await cam.stop()

    asyncio.run(main())


def test_conflicting_capture_settings_are_refused() -> None:
    rec = Recorder()
    ctx = rec.ctx(static_scene((0.0, 0.0, 0.0), []))
    cam = CameraPlugin(CameraConfig.model_validate({"type": "camera", "width": 320, "height": 240}), ctx)
    tag = AprilTagPlugin(AprilTagConfig.model_validate({"type": "apriltag", "width": 640}), ctx)

    async def main() -> None:
        await cam.start()
        try:
            with pytest.raises(CaptureConfigError, match="'width' differs"):
                await tag.start()
        finally:
            await tag.stop()
            await cam.stop()

    asyncio.run(main())
    assert capture_threads() == []


def test_config_rejects_unknown_and_bad_fields() -> None:
    from pydantic import ValidationError

    with pytest.raises(ValidationError):
        AprilTagConfig.model_validate({"type": "apriltag", "tag_size": 0.1})  # typo: tag_size_m
    with pytest.raises(ValidationError):
        CameraConfig.model_validate({"type": "camera", "jpeg_quality": 500})
    with pytest.raises(ValidationError):
        AprilTagConfig.model_validate({"type": "apriltag", "quad_decimate": 0})


def test_plugin_modules_do_not_import_vision_libraries() -> None:
    """The agent must start without the vision extra when no camera is configured."""
    code = (
        "import sys\n"
        "import robot_agent.sensors.camera, robot_agent.sensors.apriltag\n"
        "bad = [m for m in ('cv2', 'numpy', 'dt_apriltags') if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
