"""The runs' frame store: camera frames kept as JPEG files on disk, one folder per run and robot.

``<root>/<run id>/<robot id>/<ts in ns>_<frame seq>.jpg``: the file name carries the robot's time stamp,
so an export reads frames in time order without a database table, and a crash loses nothing already
written (files are written to a temporary name and renamed). Writing happens on a thread of its own: the
event loop only queues a frame (a full queue drops it, counted). The store has a quota over all runs; the
caller asks :meth:`FrameStore.reserve` before queueing, so the quota is never exceeded.
"""

from __future__ import annotations

import bisect
import contextlib
import logging
import os
import queue
import shutil
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)
#: how far past ``at`` a frame still counts as "at or before" it (float rounding of epoch seconds, not time)
AT_SLACK_NS = 1000

#: frames waiting for the disk; beyond this they are dropped (counted)
QUEUE_MAX = 256


@dataclass(frozen=True, slots=True)
class StoredFrame:
    robot_id: str
    ts: float
    frame_seq: int
    path: Path


def safe_name(robot_id: str) -> bool:
    """A robot id usable as a folder name (ids come from MQTT topics: no '/', but be strict anyway)."""
    return bool(robot_id) and robot_id not in (".", "..") and "/" not in robot_id and "\\" not in robot_id


class FrameStore:
    def __init__(self, *, root: Path, quota_bytes: int) -> None:
        self.root = root
        self.quota_bytes = quota_bytes
        self.used_bytes = 0
        self.written = 0
        self.dropped = 0
        self.errors = 0
        self._queue: queue.Queue[tuple[Path, bytes] | None] = queue.Queue(QUEUE_MAX)
        self._thread: threading.Thread | None = None

    # -- lifecycle -------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Measure what is stored already (the quota counts it), then start the writer thread."""
        self.used_bytes = self._measure()
        self._thread = threading.Thread(target=self._run, name="run-frames", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout=10)
            self._thread = None

    def _measure(self) -> int:
        if not self.root.is_dir():
            return 0
        total = 0
        for dirpath, _, files in os.walk(self.root):
            for f in files:
                with contextlib.suppress(OSError):
                    total += os.path.getsize(os.path.join(dirpath, f))
        return total

    # -- recording (event loop) ------------------------------------------------------------------------------
    def reserve(self, n: int) -> bool:
        """Count ``n`` bytes against the quota; False (nothing counted) when they would exceed it."""
        if self.used_bytes + n > self.quota_bytes:
            return False
        self.used_bytes += n
        return True

    def put(self, run_id: int, robot_id: str, ts: float, frame_seq: int, jpeg: bytes) -> bool:
        path = self.root / str(run_id) / robot_id / f"{round(ts * 1e9):019d}_{frame_seq}.jpg"
        try:
            self._queue.put_nowait((path, jpeg))
        except queue.Full:
            self.used_bytes -= len(jpeg)
            self.dropped += 1
            return False
        return True

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                self._queue.task_done()
                return
            path, jpeg = item
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(".part")
                tmp.write_bytes(jpeg)
                os.replace(tmp, path)
                self.written += 1
            except OSError as exc:
                self.errors += 1
                self.used_bytes -= len(jpeg)
                log.error("frame not stored at %s: %s", path, exc)
            finally:
                self._queue.task_done()

    def flush(self, timeout: float = 5.0) -> None:
        """Wait (blocking: call it in a thread) until the frames queued so far are on disk."""
        deadline = time.monotonic() + timeout
        while self._queue.unfinished_tasks and self._thread is not None and time.monotonic() < deadline:
            time.sleep(0.01)

    # -- reading (threads) ------------------------------------------------------------------------------------
    def run_dir(self, run_id: int) -> Path:
        return self.root / str(run_id)

    def frames(self, run_id: int) -> Iterator[StoredFrame]:
        """Every stored frame of a run, in time order (robots merged)."""
        base = self.run_dir(run_id)
        if not base.is_dir():
            return
        found: list[tuple[int, str, int, Path]] = []
        for robot_dir in sorted(p for p in base.iterdir() if p.is_dir()):
            for f in robot_dir.iterdir():
                if f.suffix != ".jpg":
                    continue
                stem_ts, _, stem_seq = f.stem.partition("_")
                try:
                    found.append((int(stem_ts), robot_dir.name, int(stem_seq or 0), f))
                except ValueError:
                    continue
        found.sort()
        for ts_ns, robot_id, seq, path in found:
            yield StoredFrame(robot_id, ts_ns / 1e9, seq, path)

    def _listing(self, run_id: int, robot_id: str) -> tuple[Path, list[str]]:
        """A robot's frame files of a run, sorted: the names are fixed-width time stamps, so this is time
        order (no index to keep; a seek costs one directory listing)."""
        folder = self.run_dir(run_id) / robot_id
        if not safe_name(robot_id):
            return folder, []
        try:
            return folder, sorted(n for n in os.listdir(folder) if n.endswith(".jpg"))
        except OSError:
            return folder, []

    @staticmethod
    def _parse(name: str) -> tuple[int, int] | None:
        stem_ts, _, stem_seq = name[:-4].partition("_")
        try:
            return int(stem_ts), int(stem_seq or 0)
        except ValueError:  # a stray file
            return None

    def frame_at(self, run_id: int, robot_id: str, at: float) -> StoredFrame | None:
        """The robot's newest frame of the run at or before ``at`` (the replay's camera), or None."""
        folder, names = self._listing(run_id, robot_id)
        # '~' sorts after every digit: frames stamped exactly at ``at`` count. A float of epoch seconds holds
        # only ~0.25 us near today's time, so a frame's own ts (from frame_times) read back here may land a
        # few hundred ns before its name: AT_SLACK_NS counts those as "at" (frames are >= 1 ms apart).
        key = f"{round(at * 1e9) + AT_SLACK_NS:019d}_~"
        for i in range(bisect.bisect_right(names, key) - 1, -1, -1):
            parsed = self._parse(names[i])
            if parsed is not None:
                return StoredFrame(robot_id, parsed[0] / 1e9, parsed[1], folder / names[i])
        return None

    def frame_times(self, run_id: int, robot_id: str) -> list[tuple[float, int]]:
        """(ts, frame_seq) of every stored frame of the robot in the run, in time order."""
        _, names = self._listing(run_id, robot_id)
        return [(p[0] / 1e9, p[1]) for p in map(self._parse, names) if p is not None]

    def usage(self, run_id: int) -> tuple[int, int]:
        """(frames, bytes) stored for a run."""
        n = size = 0
        for f in self.frames(run_id):
            n += 1
            with contextlib.suppress(OSError):
                size += f.path.stat().st_size
        return n, size

    def delete(self, run_id: int) -> int:
        """Remove a run's frames; returns the bytes freed."""
        base = self.run_dir(run_id)
        if not base.is_dir():
            return 0
        freed = sum(f.stat().st_size for f in base.rglob("*") if f.is_file())
        shutil.rmtree(base, ignore_errors=True)
        self.used_bytes = max(0, self.used_bytes - freed)
        return freed
