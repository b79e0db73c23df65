"""Exports of a run: MCAP (mcap.py), Parquet (one file per stream, typed columns) and a zip of
both with ``run.json`` and the camera JPEGs.

Everything is streamed: a worker thread writes the export into a sink whose chunks the HTTP response sends
as they come (a bounded queue: a slow client slows the writer, memory stays flat), reading the database
one batch of rows at a time. A client that goes away stops the worker at its next write.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import shutil
import tempfile
import threading
import zipfile
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from typing import IO, Any, cast

import orjson
import pyarrow as pa
import pyarrow.parquet as pq
from sqlalchemy import Engine

from backend.services.runs.frames import FrameStore, StoredFrame
from backend.services.runs.mcap import RunSource, write_run
from backend.store import runs as store

log = logging.getLogger(__name__)

CHUNK_BYTES = 256 * 1024
QUEUE_CHUNKS = 16
#: rows per Parquet record batch
BATCH_ROWS = 10_000
_END = object()


class ExportCancelled(Exception):
    """The client went away: the worker stops writing."""


class QueueSink:
    """A write-only, non-seekable file whose bytes go to a bounded queue in chunks."""

    def __init__(self, q: queue.Queue[Any], cancelled: threading.Event) -> None:
        self._q = q
        self._cancelled = cancelled
        self._buf = bytearray()
        self._pos = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        n = len(data)
        self._buf += data
        self._pos += n
        if len(self._buf) >= CHUNK_BYTES:
            self._send()
        return n

    def _send(self) -> None:
        chunk, self._buf = bytes(self._buf), bytearray()
        while True:
            if self._cancelled.is_set():
                raise ExportCancelled
            try:
                self._q.put(chunk, timeout=0.5)
                return
            except queue.Full:
                continue

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if self._buf:
            self._send()


class Counting:
    """Adds ``tell`` to a write-only stream (a zip member): what the mcap writer asks of its output."""

    def __init__(self, inner: IO[bytes]) -> None:
        self._inner = inner
        self._pos = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        self._inner.write(data)
        self._pos += len(data)
        return len(data)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        self._inner.flush()


async def stream(produce: Callable[[IO[bytes]], object]) -> AsyncIterator[bytes]:
    """Run ``produce`` on a thread of its own and yield what it writes, chunk by chunk."""
    q: queue.Queue[Any] = queue.Queue(QUEUE_CHUNKS)
    cancelled = threading.Event()
    sink = QueueSink(q, cancelled)

    def work() -> None:
        outcome: Any = _END
        try:
            produce(cast(IO[bytes], sink))
            sink.close()
        except ExportCancelled:
            return
        except Exception as exc:
            log.exception("run export failed")
            outcome = exc
        while not cancelled.is_set():
            try:
                q.put(outcome, timeout=0.5)
                return
            except queue.Full:
                continue

    def next_chunk() -> Any:
        """The next item, or _END once cancelled (a pool thread never waits on the queue for ever)."""
        while not cancelled.is_set():
            try:
                return q.get(timeout=0.5)
            except queue.Empty:
                continue
        return _END

    thread = threading.Thread(target=work, name="run-export", daemon=True)
    thread.start()
    try:
        while True:
            item = await asyncio.to_thread(next_chunk)
            if item is _END:
                return
            if isinstance(item, Exception):
                raise item
            yield item
    finally:
        cancelled.set()
        with contextlib.suppress(queue.Empty):
            while True:
                q.get_nowait()


# --- what an export reads --------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunExport:
    engine: Engine
    frames: FrameStore
    run: dict[str, Any]
    markers: list[dict[str, Any]]
    summary: dict[str, Any]
    site: dict[str, Any]
    #: the end of what is exported (the run's end, "now" for a running run, or the end of a range)
    end: float
    #: the start of what is exported (None: the run's start)
    start: float | None = None

    @property
    def begin(self) -> float:
        return float(self.run["started_at"]) if self.start is None else self.start

    @property
    def ranged(self) -> bool:
        ended = self.run["ended_at"]
        return self.begin > self.run["started_at"] or (ended is not None and self.end < ended)

    def frames_in_range(self) -> Iterator[StoredFrame]:
        return (f for f in self.frames.frames(self.run["id"]) if self.begin <= f.ts <= self.end)

    @property
    def robots(self) -> list[str]:
        return list(self.run["robots"])

    def source(self) -> RunSource:
        start, end, robots = self.begin, self.end, self.robots
        return RunSource(
            telemetry=store.iter_telemetry(self.engine, robots, start, end),
            frames=self.frames_in_range(),
            events=store.iter_events(self.engine, robots, start, end),
            commands=store.iter_commands(self.engine, robots, start, end),
            markers=self.markers,
            geometry=store.last_before(self.engine, robots, "lighthouse_geometry", start),
            clock_offsets=store.clock_offsets(self.engine, robots, start, end),
        )

    def run_json(self) -> dict[str, Any]:
        return {
            "run": {
                **self.run,
                "running": self.run["ended_at"] is None,
                "exported_from": self.begin,
                "exported_until": self.end,
                "range": self.ranged,
            },
            "markers": self.markers,
            "summary": self.summary,
            "site": self.site,
        }


def read_frame(frame: StoredFrame) -> bytes | None:
    try:
        return frame.path.read_bytes()
    except OSError:
        return None


def write_mcap(export: RunExport, out: IO[bytes]) -> dict[str, int]:
    """Returns the messages written per topic."""
    run = {**export.run, "exported_from": export.begin, "exported_until": export.end}
    return write_run(out, run, export.source(), export.site, read_frame)


# --- Parquet ---------------------------------------------------------------------------------------------

BASE_COLUMNS = ("robot_id", "ts", "recv_ts", "seq")


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "str"
    return "json"


def _arrow_type(kinds: set[str]) -> pa.DataType:
    if kinds == {"bool"}:
        return pa.bool_()
    if kinds == {"int"}:
        return pa.int64()
    if kinds <= {"int", "float"}:
        return pa.float64()
    if kinds == {"str"}:
        return pa.string()
    return pa.string()  # nested values (lists, objects) and mixed kinds: JSON text


def column_name(field: str) -> str:
    """A data field named like a base column (``seq`` of position) is kept as ``data.<name>``."""
    return f"data.{field}" if field in BASE_COLUMNS else field


def parquet_schema(engine: Engine, robots: list[str], start: float, end: float, stream: str) -> pa.Schema:
    """First pass over a stream: every field seen, with the narrowest type that holds all its values."""
    kinds: dict[str, set[str]] = {}
    for row in store.iter_telemetry(engine, robots, start, end, stream):
        data = orjson.loads(row.payload)
        if not isinstance(data, dict):
            data = {"value": data}
        for k, v in data.items():
            if v is not None:
                kinds.setdefault(k, set()).add(_kind(v))
            else:
                kinds.setdefault(k, set())
    fields = [
        pa.field("robot_id", pa.string()),
        pa.field("ts", pa.float64()),
        pa.field("recv_ts", pa.float64()),  # server clock, when it was received (null: before it was stored)
        pa.field("seq", pa.int64()),
    ]
    fields += [pa.field(column_name(k), _arrow_type(v) if v else pa.string()) for k, v in kinds.items()]
    return pa.schema(fields)


def _cell(value: Any, typ: pa.DataType) -> Any:
    if value is None:
        return None
    if pa.types.is_string(typ) and not isinstance(value, str):
        return orjson.dumps(value).decode()
    if pa.types.is_floating(typ):
        return float(value)
    return value


def write_parquet(engine: Engine, robots: list[str], start: float, end: float, stream: str, out: Any) -> int:
    """One stream as Parquet (second pass: rows in batches); returns the rows written."""
    schema = parquet_schema(engine, robots, start, end, stream)
    data_fields = [(f.name, f.name[5:] if f.name.startswith("data.") else f.name, f.type) for f in schema][4:]
    n = 0
    with pq.ParquetWriter(out, schema, compression="zstd") as writer:
        cols: dict[str, list[Any]] = {f.name: [] for f in schema}

        def flush() -> None:
            if cols["ts"]:
                writer.write_batch(pa.RecordBatch.from_pydict(cols, schema=schema))
                for v in cols.values():
                    v.clear()

        for row in store.iter_telemetry(engine, robots, start, end, stream):
            data = orjson.loads(row.payload)
            if not isinstance(data, dict):
                data = {"value": data}
            cols["robot_id"].append(row.robot_id)
            cols["ts"].append(row.ts)
            cols["recv_ts"].append(row.recv_ts)
            cols["seq"].append(row.seq)
            for col, key, typ in data_fields:
                cols[col].append(_cell(data.get(key), typ))
            n += 1
            if len(cols["ts"]) >= BATCH_ROWS:
                flush()
        flush()
    return n


def _parquet_members(export: RunExport, zf: zipfile.ZipFile, prefix: str) -> None:
    start, end = export.begin, export.end
    for stream_name in store.streams_of(export.engine, export.robots, start, end):
        # pyarrow wants a seekable file: each stream goes through a temporary file on disk, then into the zip
        with tempfile.TemporaryFile() as tmp:
            write_parquet(export.engine, export.robots, start, end, stream_name, tmp)
            tmp.seek(0)
            with zf.open(f"{prefix}{stream_name}.parquet", "w", force_zip64=True) as member:
                shutil.copyfileobj(tmp, member, CHUNK_BYTES)


def write_parquet_zip(export: RunExport, out: IO[bytes]) -> None:
    """``format=parquet``: one Parquet file per stream (a zip, stored: Parquet is compressed already)."""
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_STORED) as zf:
        _parquet_members(export, zf, "")


def write_bundle(export: RunExport, out: IO[bytes]) -> None:
    """``format=zip``: run.json, the MCAP, the Parquet files and the camera JPEGs."""
    run_id = export.run["id"]
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_STORED) as zf:
        zf.writestr("run.json", orjson.dumps(export.run_json(), option=orjson.OPT_INDENT_2))
        with zf.open(f"run-{run_id}.mcap", "w", force_zip64=True) as member:
            write_mcap(export, cast(IO[bytes], Counting(member)))
        _parquet_members(export, zf, "parquet/")
        for frame in export.frames_in_range():
            jpeg = read_frame(frame)
            if jpeg is not None:
                zf.writestr(f"frames/{frame.robot_id}/{frame.path.name}", jpeg)
