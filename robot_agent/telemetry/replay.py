"""The replay ring: each stream's recent telemetry, kept so the server can ask for what the broker dropped.

Bounded by age (``window_s``, default 10 minutes) and by size (``max_bytes``, default 50 MB over all
streams, counted as payload bytes plus ``ENTRY_OVERHEAD`` per message); the oldest message anywhere goes
first. Messages are kept exactly as published (the bytes), so a replay carries the original ``ts``.

Optionally on disk (:class:`ReplayDisk`, ``--replay-dir``): every message is also appended to segment
files, which a restarted agent loads back (under the previous boot id), so a gap that opened just before
a restart can still be repaired. Used only from the agent's asyncio loop.
"""

from __future__ import annotations

import asyncio
import bisect
import collections
import logging
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

log = logging.getLogger(__name__)

DEFAULT_WINDOW_S = 600.0
DEFAULT_MAX_BYTES = 50_000_000
#: the agent's ring ages out old messages and writes its disk buffer this often (:meth:`ReplayRing.run`)
MAINTAIN_S = 1.0
#: what one kept message costs beyond its payload (list slots, the float and int objects, the bytes header,
#: the eviction queue entry; measured with tracemalloc: ~300 bytes for a 120-byte position message)
ENTRY_OVERHEAD = 180

SeqRange = tuple[int, int]


class _StreamRing:
    """One (boot, stream): parallel lists with a moving head (seq ascending), so lookups bisect."""

    __slots__ = ("head", "payloads", "seqs", "times")

    def __init__(self) -> None:
        self.seqs: list[int] = []
        self.times: list[float] = []
        self.payloads: list[bytes] = []
        self.head = 0

    def append(self, seq: int, t: float, payload: bytes) -> None:
        self.seqs.append(seq)
        self.times.append(t)
        self.payloads.append(payload)

    def pop_oldest(self) -> int:
        size = len(self.payloads[self.head])
        self.payloads[self.head] = b""
        self.head += 1
        if self.head > 1024 and self.head * 2 > len(self.seqs):
            del self.seqs[: self.head], self.times[: self.head], self.payloads[: self.head]
            self.head = 0
        return size

    def oldest_time(self) -> float:
        return self.times[self.head]

    def __len__(self) -> int:
        return len(self.seqs) - self.head

    def find(self, lo: int, hi: int) -> tuple[list[tuple[int, bytes]], list[SeqRange]]:
        """Messages with lo <= seq <= hi, and the sub-ranges of [lo, hi] that are not here."""
        i = bisect.bisect_left(self.seqs, lo, self.head)
        found: list[tuple[int, bytes]] = []
        missing: list[SeqRange] = []
        expect = lo
        while i < len(self.seqs) and self.seqs[i] <= hi:
            seq = self.seqs[i]
            if seq > expect:
                missing.append((expect, seq - 1))
            if seq >= expect:
                found.append((seq, self.payloads[i]))
                expect = seq + 1
            i += 1
        if expect <= hi:
            missing.append((expect, hi))
        return found, missing


class ReplayRing:
    def __init__(
        self,
        boot: str,
        *,
        window_s: float = DEFAULT_WINDOW_S,
        max_bytes: int = DEFAULT_MAX_BYTES,
        disk: ReplayDisk | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.boot = boot
        self.window_s = window_s
        self.max_bytes = max_bytes
        self._disk = disk
        self._clock = clock
        self._rings: dict[tuple[str, str], _StreamRing] = {}
        #: (boot, stream) of every kept message, oldest first: the global eviction order
        self._order: collections.deque[tuple[str, str]] = collections.deque()
        self.bytes = 0
        self.evicted = 0
        if disk is not None:
            for rec in disk.load(self._clock() - window_s):
                self._keep(rec.boot, rec.stream, rec.seq, rec.t, rec.payload)
            self._evict()

    def add(self, stream: str, seq: int, payload: bytes) -> None:
        """Keep a message of this boot (called for every telemetry message published)."""
        t = self._clock()
        # A copy of exactly its size: orjson's output keeps a 4 KiB allocation behind even a 100-byte
        # message (measured with tracemalloc), which would make the ring 30 times its counted size.
        payload = memoryview(payload).tobytes()
        self._keep(self.boot, stream, seq, t, payload)
        if self._disk is not None:
            self._disk.append(self.boot, stream, seq, t, payload)
        self._evict()

    def _keep(self, boot: str, stream: str, seq: int, t: float, payload: bytes) -> None:
        key = (boot, stream)
        ring = self._rings.get(key)
        if ring is None:
            ring = self._rings[key] = _StreamRing()
        elif ring.seqs and seq <= ring.seqs[-1]:
            return  # a disk record loaded twice, or out of order: the first copy stays
        ring.append(seq, t, payload)
        self._order.append(key)
        self.bytes += len(payload) + ENTRY_OVERHEAD

    def _evict(self) -> None:
        horizon = self._clock() - self.window_s
        order, rings = self._order, self._rings
        while order:
            ring = rings[order[0]]
            if self.bytes <= self.max_bytes and ring.oldest_time() >= horizon:
                break
            key = order.popleft()
            self.bytes -= ring.pop_oldest() + ENTRY_OVERHEAD
            self.evicted += 1
            if not len(ring):
                del rings[key]

    def maintain(self) -> None:
        """Periodic: age out old messages even when nothing new arrives, push disk writes out."""
        self._evict()
        if self._disk is not None:
            self._disk.flush(self._clock() - self.window_s)

    async def run(self, period_s: float = MAINTAIN_S) -> None:
        """:meth:`maintain` every ``period_s``, as an asyncio task of the agent's, until cancelled."""
        while True:
            await asyncio.sleep(period_s)
            self.maintain()

    def lookup(self, boot: str, stream: str, ranges: list[SeqRange]) -> tuple[list[tuple[int, bytes]], list[SeqRange]]:
        """Kept messages in ``ranges`` (seq order) and the asked-for ranges that are gone or never existed."""
        self._evict()
        ring = self._rings.get((boot, stream))
        found: list[tuple[int, bytes]] = []
        missing: list[SeqRange] = []
        for lo, hi in sorted(ranges):
            if ring is None:
                missing.append((lo, hi))
                continue
            f, m = ring.find(lo, hi)
            found += f
            missing += m
        return found, missing

    def stats(self) -> dict[str, int]:
        return {"messages": len(self._order), "bytes": self.bytes, "evicted": self.evicted, "streams": len(self._rings)}

    def close(self) -> None:
        if self._disk is not None:
            self._disk.close()


# --------------------------------------------------------------------------------------------------
# On disk: append-only segment files, one series per boot.
# --------------------------------------------------------------------------------------------------

#: record: stream length, seq, wall time, payload length; then the stream name and the payload
_REC = struct.Struct(">BQdI")
SEGMENT_BYTES = 4 * 1024 * 1024
SUFFIX = ".ring"


@dataclass(frozen=True, slots=True)
class DiskRecord:
    boot: str
    stream: str
    seq: int
    t: float
    payload: bytes


class ReplayDisk:
    """Segment files ``{boot}.{n:06d}.ring`` in ``directory``: appended through a buffer that
    :meth:`flush` writes out (about once a second, and at shutdown: a crash loses at most that last
    second). Old segments go when they are older than the window or the directory exceeds ``max_bytes``."""

    def __init__(self, directory: Path, boot: str, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        self.dir = directory
        self.dir.mkdir(parents=True, exist_ok=True)
        self.boot = boot
        self.max_bytes = max_bytes
        self._index = 0
        self._file: BinaryIO | None = None
        self._path: Path | None = None
        self._written = 0
        self.write_errors = 0
        #: time of the newest record of each segment (read by load, kept by append): what ages it out
        self._newest: dict[Path, float] = {}

    def _segments(self) -> list[tuple[Path, float, int]]:
        """(path, time of its newest record, size) of every segment, oldest first."""
        out = []
        for path in self.dir.glob(f"*{SUFFIX}"):
            try:
                st = path.stat()
            except OSError:
                continue  # deleted meanwhile
            out.append((path, self._newest.get(path, st.st_mtime), st.st_size))
        return sorted(out, key=lambda e: (e[1], e[0].name))

    def load(self, since: float) -> Iterator[DiskRecord]:
        """Records of earlier boots not older than ``since``, oldest segment first; a torn tail is skipped."""
        for path, _mtime, _size in self._segments():
            boot = path.name.split(".", 1)[0]
            try:
                data = path.read_bytes()
            except OSError as exc:
                log.warning("replay segment %s unreadable: %s", path, exc)
                continue
            pos = 0
            while pos + _REC.size <= len(data):
                slen, seq, t, plen = _REC.unpack_from(data, pos)
                end = pos + _REC.size + slen + plen
                if end > len(data):
                    break  # written half when the agent stopped
                stream = data[pos + _REC.size : pos + _REC.size + slen].decode("utf-8", "replace")
                self._newest[path] = max(t, self._newest.get(path, t))
                if t >= since:
                    yield DiskRecord(boot, stream, seq, t, data[pos + _REC.size + slen : end])
                pos = end

    def append(self, boot: str, stream: str, seq: int, t: float, payload: bytes) -> None:
        name = stream.encode()
        if self._file is None or self._written >= SEGMENT_BYTES:
            self._open_next(boot)
        if self._file is None:
            return
        rec = _REC.pack(len(name), seq, t, len(payload)) + name + payload
        try:
            self._file.write(rec)
            self._written += len(rec)
            if self._path is not None:
                self._newest[self._path] = t
        except OSError as exc:
            self._disk_error(exc)

    def _open_next(self, boot: str) -> None:
        self.close()
        self._index += 1
        path = self.dir / f"{boot}.{self._index:06d}{SUFFIX}"
        try:
            self._file = open(path, "ab", buffering=256 * 1024)  # noqa: SIM115 - closed in close()
            self._path = path
            self._written = 0
        except OSError as exc:
            self._disk_error(exc)

    def _disk_error(self, exc: OSError) -> None:
        self.write_errors += 1
        if self.write_errors == 1 or self.write_errors % 1000 == 0:
            log.warning("replay ring on disk: write failed (%d so far): %s", self.write_errors, exc)

    def flush(self, horizon: float) -> None:
        if self._file is not None:
            try:
                self._file.flush()
            except OSError as exc:
                self._disk_error(exc)
        current = self._path if self._file is not None else None
        segments = self._segments()
        total = sum(size for _p, _m, size in segments)
        for path, mtime, size in segments:
            if path == current:
                continue
            if total <= self.max_bytes and mtime >= horizon:
                break
            total -= size
            path.unlink(missing_ok=True)
            self._newest.pop(path, None)

    def close(self) -> None:
        if self._file is not None:
            try:
                self._file.close()
            except OSError as exc:
                self._disk_error(exc)
            self._file = None
