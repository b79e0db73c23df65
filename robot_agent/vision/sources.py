"""Camera frame sources and the one capture the camera and apriltag plugins share.

A :class:`FrameSource` is blocking (``open``/``read``/``close``) and runs in the capture thread of a
:class:`SharedCapture`; the plugins only ever ``await`` the latest frame, so a slow camera never blocks
the agent's event loop. Both plugins see the same ``frame_seq`` for the same frame, which is how the
browser matches detections to JPEG frames.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import logging
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from robot_agent.vision.settings import CaptureSettings, Intrinsics

log = logging.getLogger(__name__)

Image = npt.NDArray[Any]


class SourceError(RuntimeError):
    """The camera cannot be opened or stopped delivering frames (message says which and why)."""


class CaptureConfigError(ValueError):
    """The camera and apriltag plugins ask for different capture settings."""


class FrameSource(ABC):
    """A blocking frame source. ``read`` returns (source frame number, epoch seconds, BGR image)."""

    def __init__(self) -> None:
        self._seq = 0

    @abstractmethod
    def open(self) -> None: ...

    @abstractmethod
    def grab(self) -> Image:
        """One BGR frame (blocks until the device has one)."""

    def read(self) -> tuple[int, float, Image]:
        img = self.grab()
        self._seq += 1
        return self._seq, time.time(), img

    @abstractmethod
    def close(self) -> None: ...

    #: Whether ``read`` paces itself (a real camera) or must be paced by the capture loop.
    self_paced: bool = False


class OpenCVSource(FrameSource):
    """``cv2.VideoCapture`` on a USB camera index or a video file (files loop at the end)."""

    def __init__(self, device: int | str, width: int, height: int, fps: float) -> None:
        super().__init__()
        if isinstance(device, str) and device.strip().isdigit():
            device = int(device.strip())
        self.device = device
        self.width, self.height, self.fps = width, height, fps
        self.is_file = isinstance(device, str)
        self.self_paced = not self.is_file
        self._cap: Any = None

    def open(self) -> None:
        import cv2

        if isinstance(self.device, str):
            if not Path(self.device).is_file():
                raise SourceError(f"video file not found: {self.device}")
            cap = cv2.VideoCapture(self.device)
        else:
            cap = cv2.VideoCapture(self.device)
        if not cap.isOpened():
            cap.release()
            what = f"video file {self.device}" if self.is_file else f"camera index {self.device}"
            raise SourceError(f"cannot open {what} (device missing or busy?)")
        if not self.is_file:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
            cap.set(cv2.CAP_PROP_FPS, self.fps)
        self._cap = cap

    def grab(self) -> Image:
        import cv2

        if self._cap is None:
            raise SourceError("source not open")
        ok, frame = self._cap.read()
        if not ok and self.is_file:  # loop the file
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, frame = self._cap.read()
        if not ok or frame is None:
            raise SourceError(f"no frame from {self.device}")
        if frame.ndim == 2:
            frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        return frame

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class Picamera2Source(FrameSource):
    """The Raspberry Pi camera through Picamera2 (imported only when opened)."""

    self_paced = True

    def __init__(self, width: int, height: int, fps: float) -> None:
        super().__init__()
        self.width, self.height, self.fps = width, height, fps
        self._cam: Any = None

    def open(self) -> None:
        try:
            picamera2 = importlib.import_module("picamera2")
        except ImportError as exc:
            raise SourceError(f"picamera2 is not installed ({exc}); install python3-picamera2") from None
        try:
            cam = picamera2.Picamera2()
            # Picamera2's "RGB888" is laid out B, G, R in memory: what OpenCV calls BGR.
            cfg = cam.create_video_configuration(
                main={"size": (self.width, self.height), "format": "RGB888"},
                controls={"FrameRate": float(self.fps)},
            )
            cam.configure(cfg)
            cam.start()
        except Exception as exc:
            raise SourceError(f"cannot open the Pi camera: {exc}") from exc
        self._cam = cam

    def grab(self) -> Image:
        if self._cam is None:
            raise SourceError("source not open")
        frame = np.asarray(self._cam.capture_array("main"))
        if frame.ndim == 3 and frame.shape[2] == 4:  # XRGB8888 -> drop the padding channel
            frame = np.ascontiguousarray(frame[:, :, :3])
        return frame

    def close(self) -> None:
        if self._cam is not None:
            with contextlib.suppress(Exception):
                self._cam.stop()
            with contextlib.suppress(Exception):
                self._cam.close()
            self._cam = None


class SimCameraSource(FrameSource):
    """Renders the simulated world from the robot's current pose (see :mod:`sim_camera`)."""

    def __init__(self, settings: CaptureSettings, scene: Any) -> None:
        super().__init__()
        self.settings = settings
        self.scene = scene
        self._camera: Any = None

    def open(self) -> None:
        from robot_agent.vision.sim_camera import SimCamera

        self._camera = SimCamera(self.settings)

    def grab(self) -> Image:
        if self._camera is None:
            raise SourceError("source not open")
        return self._camera.render(self.scene.pose(), self.scene.tags())

    def close(self) -> None:
        self._camera = None


def make_source(settings: CaptureSettings, world: Any = None) -> FrameSource:
    """The source ``settings.source`` names; ``auto`` picks sim (simulating), Picamera2, else OpenCV."""
    kind = settings.source
    if kind == "auto":
        if world is not None:
            kind = "sim"
        else:
            try:
                importlib.import_module("picamera2")
                kind = "picamera2"
            except ImportError:
                kind = "opencv"
    if kind == "sim":
        if world is None:
            raise SourceError("the simulated camera needs the simulated world (run the agent with --simulate)")
        from robot_agent.vision.sim_camera import Scene, scene_from_world

        scene = world if isinstance(world, Scene) else scene_from_world(world)
        return SimCameraSource(settings, scene)
    if kind == "picamera2":
        return Picamera2Source(settings.width, settings.height, settings.fps)
    return OpenCVSource(settings.device, settings.width, settings.height, settings.fps)


@dataclass(frozen=True, slots=True)
class Frame:
    """A captured frame. ``seq`` counts frames of the shared capture (+1 per frame, never reused)."""

    seq: int
    ts: float
    image: Image
    intrinsics: Intrinsics

    @property
    def size(self) -> tuple[int, int]:
        h, w = self.image.shape[:2]
        return int(w), int(h)


class SharedCapture:
    """One camera for every plugin that needs frames; lives in ``SensorContext.shared["camera"]``.

    Plugins :meth:`attach` with their config (the capture fields they set explicitly are merged) and
    :meth:`detach` when they stop; the capture thread runs while at least one is attached.
    """

    def __init__(self, world: Any = None) -> None:
        self._world = world
        self._owners: dict[str, dict[str, Any]] = {}
        self.settings = CaptureSettings()
        self._source: FrameSource | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = asyncio.Lock()
        self._seq = 0
        self._latest: Frame | None = None
        self._error: BaseException | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._event: asyncio.Event | None = None
        self.frames_captured = 0

    @classmethod
    def of(cls, shared: dict[str, Any], world: Any = None) -> SharedCapture:
        cap = shared.get("camera")
        if not isinstance(cap, SharedCapture):
            cap = cls(world)
            shared["camera"] = cap
        return cap

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def latest(self) -> Frame | None:
        return self._latest

    def _merged(self, owners: dict[str, dict[str, Any]]) -> CaptureSettings:
        merged: dict[str, Any] = {}
        origin: dict[str, str] = {}
        for owner, fields in sorted(owners.items()):
            for name, value in fields.items():
                if name in merged and merged[name] != value:
                    raise CaptureConfigError(
                        f"capture setting {name!r} differs between sensors {origin[name]!r} "
                        f"({merged[name]!r}) and {owner!r} ({value!r}); they share one camera: "
                        "set it once or identically"
                    )
                merged[name] = value
                origin[name] = owner
        return CaptureSettings(**merged)

    async def attach(self, owner: str, explicit: dict[str, Any]) -> CaptureSettings:
        """Register ``owner`` and make sure the capture runs with the merged settings. Raises
        :class:`SourceError` (device missing) or :class:`CaptureConfigError` (conflicting settings)."""
        async with self._lock:
            owners = {**self._owners, owner: dict(explicit)}
            settings = self._merged(owners)
            self._loop = asyncio.get_running_loop()
            if self._event is None:
                self._event = asyncio.Event()
            if self.running and settings != self.settings:
                await asyncio.to_thread(self._shutdown)
            if not self.running:
                await asyncio.to_thread(self._open, settings)
            self._owners = owners
            return self.settings

    async def detach(self, owner: str) -> None:
        async with self._lock:
            self._owners.pop(owner, None)
            if not self._owners:
                await asyncio.to_thread(self._shutdown)

    def _open(self, settings: CaptureSettings) -> None:
        source = make_source(settings, self._world)
        source.open()  # raises SourceError with the reason
        self.settings = settings
        self._source = source
        self._error = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, args=(source, settings), name="camera-capture", daemon=True)
        self._thread.start()

    def _shutdown(self) -> None:
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=5.0)
        self._latest = None  # never hand out a frame from a closed session
        source, self._source = self._source, None
        if source is not None:
            with contextlib.suppress(Exception):
                source.close()

    def _signal(self) -> None:
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        with contextlib.suppress(RuntimeError):
            loop.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        old, self._event = self._event, asyncio.Event()
        if old is not None:
            old.set()

    def _run(self, source: FrameSource, settings: CaptureSettings) -> None:
        """Capture thread: keep only the newest frame; pace sources that do not pace themselves."""
        period = 1.0 / settings.fps
        intrinsics = settings.intrinsics()
        size = (settings.width, settings.height)
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                _, ts, image = source.read()
            except Exception as exc:
                log.warning("camera capture failed: %s", exc)
                self._error = exc if isinstance(exc, SourceError) else SourceError(f"camera read failed: {exc}")
                self._signal()
                return
            h, w = image.shape[:2]
            if (w, h) != size:
                # The device or file gave another resolution than configured: keep the pose maths right
                # by scaling the intrinsics (same field of view assumed), and say so once.
                log.warning(
                    "camera delivers %dx%d, configured %dx%d: intrinsics scaled; set width/height to match",
                    w,
                    h,
                    settings.width,
                    settings.height,
                )
                intrinsics = settings.intrinsics().scaled(w / settings.width, h / settings.height)
                size = (w, h)
            self._seq += 1
            self.frames_captured += 1
            self._latest = Frame(self._seq, ts, image, intrinsics)
            self._signal()
            next_t += period
            delay = next_t - time.monotonic()
            if delay < -period:
                next_t = time.monotonic()
                delay = 0.0
            if not source.self_paced or delay > 0:
                self._stop.wait(max(0.0, delay))

    async def next_frame(self, after_seq: int, timeout: float = 5.0) -> Frame:
        """The newest frame with ``seq > after_seq``, waiting for one. Raises :class:`SourceError` if the
        camera failed or delivered nothing within ``timeout`` seconds."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            frame = self._latest
            if frame is not None and frame.seq > after_seq:
                return frame
            if self._error is not None:
                raise self._error
            if not self.running:
                raise SourceError("camera capture is not running")
            event = self._event
            remaining = deadline - loop.time()
            if event is None or remaining <= 0:
                raise SourceError(f"no camera frame within {timeout:.1f} s")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(event.wait(), min(remaining, 0.5))
