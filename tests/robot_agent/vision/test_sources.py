"""Frame sources and the shared capture: video files, the (mocked) Pi camera, missing devices."""

from __future__ import annotations

import asyncio
import math
import sys
import threading
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from robot_agent.vision.settings import CaptureSettings
from robot_agent.vision.sim_camera import TagPlacement, static_scene
from robot_agent.vision.sources import (
    CaptureConfigError,
    OpenCVSource,
    Picamera2Source,
    SharedCapture,
    SimCameraSource,
    SourceError,
    make_source,
)
from tests.robot_agent.vision.videos import write_video


def capture_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "camera-capture"]


def test_opencv_source_reads_and_loops_a_video_file(tmp_path: Path) -> None:
    path = tmp_path / "tags.avi"
    write_video(path, [1, 2, 3])
    src = OpenCVSource(str(path), 640, 480, 10.0)
    src.open()
    try:
        from robot_agent.vision.detector import TagDetector

        det = TagDetector(tag_size_m=0.15, nthreads=1)
        cam = CaptureSettings().intrinsics()
        seen = []
        for expected_seq in range(1, 8):
            seq, ts, img = src.read()
            assert seq == expected_seq and ts > 0
            assert img.shape == (480, 640, 3) and img.dtype == np.uint8
            seen.append([d["tag_id"] for d in det.detect(img, cam)])
        assert seen == [[1], [2], [3], [1], [2], [3], [1]]  # looped at the end of the file
    finally:
        src.close()


def test_opencv_source_missing_devices() -> None:
    with pytest.raises(SourceError, match="video file not found"):
        OpenCVSource("/nonexistent/cam.avi", 640, 480, 10.0).open()
    with pytest.raises(SourceError, match="cannot open camera index 63"):
        OpenCVSource("63", 640, 480, 10.0).open()


class FakePicamera2:
    """Stands in for picamera2.Picamera2 (hardware): records the configuration, returns BGR frames."""

    instances: list[FakePicamera2] = []

    def __init__(self) -> None:
        self.config: dict[str, Any] | None = None
        self.started = False
        self.closed = False
        self.n = 0
        FakePicamera2.instances.append(self)

    def create_video_configuration(self, main: dict[str, Any], controls: dict[str, Any]) -> dict[str, Any]:
        return {"main": main, "controls": controls}

    def configure(self, cfg: dict[str, Any]) -> None:
        self.config = cfg

    def start(self) -> None:
        self.started = True

    def capture_array(self, name: str) -> np.ndarray:
        assert self.started and name == "main"
        assert self.config is not None
        w, h = self.config["main"]["size"]
        self.n += 1
        frame = np.zeros((h, w, 4), np.uint8)  # XRGB8888-style padding channel
        frame[:, :, 0] = self.n
        return frame

    def stop(self) -> None:
        self.started = False

    def close(self) -> None:
        self.closed = True


@pytest.fixture
def fake_picamera2(monkeypatch: pytest.MonkeyPatch) -> type[FakePicamera2]:
    mod = types.ModuleType("picamera2")
    mod.Picamera2 = FakePicamera2  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "picamera2", mod)
    FakePicamera2.instances.clear()
    return FakePicamera2


def test_picamera2_source(fake_picamera2: type[FakePicamera2]) -> None:
    src = make_source(CaptureSettings(width=320, height=240, fps=15.0), world=None)  # auto -> Pi camera
    assert isinstance(src, Picamera2Source)
    src.open()
    cam = fake_picamera2.instances[-1]
    assert cam.config == {"main": {"size": (320, 240), "format": "RGB888"}, "controls": {"FrameRate": 15.0}}
    seq, _, img = src.read()
    assert seq == 1 and img.shape == (240, 320, 3) and int(img[0, 0, 0]) == 1
    src.close()
    assert cam.closed and not cam.started


def test_picamera2_missing_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "picamera2", None)  # import fails
    with pytest.raises(SourceError, match="picamera2 is not installed"):
        Picamera2Source(640, 480, 10.0).open()


def test_make_source_choices() -> None:
    scene = static_scene((0.0, 0.0, 0.0), [])
    assert isinstance(make_source(CaptureSettings(), world=scene), SimCameraSource)
    with pytest.raises(SourceError, match="--simulate"):
        make_source(CaptureSettings(source="sim"), world=None)
    assert isinstance(make_source(CaptureSettings(source="opencv", device="3")), OpenCVSource)


def test_shared_capture_one_thread_same_frames() -> None:
    async def main() -> None:
        tag = TagPlacement.facing(4, 0.15, 1.0, 0.0, 0.1, math.pi)
        shared: dict[str, Any] = {}
        cap = SharedCapture.of(shared, static_scene((0.0, 0.0, 0.0), [tag]))
        assert SharedCapture.of(shared) is cap
        s1 = await cap.attach("camera:camera", {"fps": 50.0})
        s2 = await cap.attach("apriltag:apriltag", {"fx": 500.0})
        assert s1.fps == s2.fps == 50.0
        assert len(capture_threads()) == 1
        f1 = await cap.next_frame(0)
        f2 = await cap.next_frame(0)
        assert f2.seq >= f1.seq >= 1  # both consumers get the newest frame, same numbering
        f3 = await cap.next_frame(f2.seq)
        assert f3.seq > f2.seq and f3.image.shape == (480, 640, 3)
        with pytest.raises(CaptureConfigError, match="'fps' differs"):
            await cap.attach("other", {"fps": 5.0})
        await cap.detach("camera:camera")
        assert cap.running  # the apriltag plugin still uses it
        await cap.detach("apriltag:apriltag")
        assert not cap.running

    asyncio.run(main())
    assert capture_threads() == []


def test_shared_capture_reconfigures_when_the_second_plugin_sets_a_field() -> None:
    async def main() -> None:
        cap = SharedCapture(static_scene((0.0, 0.0, 0.0), []))
        await cap.attach("apriltag:apriltag", {})
        first = await cap.next_frame(0)
        assert first.image.shape == (480, 640, 3)
        await cap.attach("camera:camera", {"width": 320, "height": 240})
        frame = await cap.next_frame(first.seq)
        assert frame.image.shape == (240, 320, 3) and frame.seq > first.seq
        assert frame.intrinsics.cx == 160.0
        await cap.detach("apriltag:apriltag")
        await cap.detach("camera:camera")

    asyncio.run(main())
    assert capture_threads() == []


def test_capture_failure_surfaces_to_consumers() -> None:
    class Flaky(SimCameraSource):
        def grab(self) -> np.ndarray:
            if self._seq >= 2:
                raise OSError("camera unplugged")
            return super().grab()

    async def main() -> None:
        cap = SharedCapture(static_scene((0.0, 0.0, 0.0), []))
        import robot_agent.vision.sources as sources

        orig = sources.make_source
        sources.make_source = lambda s, w=None: Flaky(s, w)  # type: ignore[assignment]
        try:
            await cap.attach("camera:camera", {"fps": 100.0})
        finally:
            sources.make_source = orig
        seq = 0
        with pytest.raises(SourceError, match="camera unplugged"):
            for _ in range(10):
                seq = (await cap.next_frame(seq, timeout=2.0)).seq
        assert seq <= 2
        await cap.detach("camera:camera")

    asyncio.run(main())
    assert capture_threads() == []


def test_resolution_mismatch_scales_intrinsics(tmp_path: Path) -> None:
    """A device that ignores the configured size: poses stay right because the intrinsics follow."""
    path = tmp_path / "v.avi"
    write_video(path, [1])  # 640x480

    async def main() -> None:
        cap = SharedCapture()
        fields = {"source": "opencv", "device": str(path), "width": 320, "height": 240}
        await cap.attach("x", {**fields, "fx": 250.0, "fy": 250.0})
        try:
            frame = await cap.next_frame(0)
            assert frame.size == (640, 480)
            assert frame.intrinsics.as_tuple() == (500.0, 500.0, 320.0, 240.0)
        finally:
            await cap.detach("x")

    asyncio.run(main())
