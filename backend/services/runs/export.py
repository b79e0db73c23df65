"""Exports of a run: MCAP (mcap.py), Parquet (one file per stream, typed columns) and a zip of
both with ``run.json`` and the camera JPEGs.

Everything is streamed: an export thread (``backend/services/telemetry/readers.py``) writes the export
into a sink whose chunks the HTTP response sends as they come (bounded: a slow client slows the writer,
memory stays flat), reading the database a chunk of rows at a time, each chunk on a connection given back
before it is written (a slow client holds no connection). A client that goes away stops the writer at its
next write.

Parquet gets a typed column per data key, for at most ``max_fields`` distinct keys per stream (the first
seen); the rest of a row's keys go, as one JSON object, in its ``other_fields`` column, so a robot that
sends a new key in every message costs one column, not a million.
"""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from typing import IO, Any, cast

import orjson
import pyarrow as pa
import pyarrow.parquet as pq
from sqlalchemy import Engine

from backend.services.runs.frames import FrameStore, StoredFrame
from backend.services.runs.mcap import RunSource, write_run
from backend.store import run_reads as reads
from backend.store import runs as store

CHUNK_BYTES = 256 * 1024
#: rows per Parquet record batch
BATCH_ROWS = 10_000
#: distinct data keys a stream's Parquet file gets a column for, unless the export says otherwise
MAX_FIELDS = 256


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
    #: Parquet: distinct data keys per stream with a column of their own (the rest: ``other_fields``)
    max_fields: int = MAX_FIELDS

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
            telemetry=reads.iter_telemetry(self.engine, robots, start, end),
            frames=self.frames_in_range(),
            events=reads.iter_events(self.engine, robots, start, end),
            commands=reads.iter_commands(self.engine, robots, start, end),
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
#: a row's data keys that have no column of their own (beyond the cap), as one JSON object (null: none)
OTHER_FIELDS = "other_fields"


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
    return f"data.{field}" if field in (*BASE_COLUMNS, OTHER_FIELDS) else field


def _data(payload: Any) -> dict[str, Any]:
    data = orjson.loads(payload)
    return data if isinstance(data, dict) else {"value": data}


@dataclass(frozen=True)
class ParquetLayout:
    """A stream's Parquet schema, and which data key fills which typed column."""

    schema: pa.Schema
    #: (column, data key, type) of the keys with a column of their own
    columns: list[tuple[str, str, pa.DataType]]
    #: some rows have keys beyond the cap: the ``other_fields`` column holds them
    other: bool


def parquet_schema(
    engine: Engine, robots: list[str], start: float, end: float, stream: str, max_fields: int = MAX_FIELDS
) -> ParquetLayout:
    """First pass over a stream: the first ``max_fields`` distinct keys seen, each with the narrowest type
    that holds all its values; whether any row has more (memory stays bounded whatever the robot sends)."""
    kinds: dict[str, set[str]] = {}
    names = set(BASE_COLUMNS)
    other = False
    for row in reads.iter_telemetry(engine, robots, start, end, stream):
        for k, v in _data(row.payload).items():
            known = kinds.get(k)
            if known is None:
                if len(kinds) >= max_fields or column_name(k) in names:
                    other = True
                    continue
                known = kinds[k] = set()
                names.add(column_name(k))
            if v is not None:
                known.add(_kind(v))
    fields = [
        pa.field("robot_id", pa.string()),
        pa.field("ts", pa.float64()),
        pa.field("recv_ts", pa.float64()),  # server clock, when it was received (null: before it was stored)
        pa.field("seq", pa.int64()),
    ]
    columns = [(column_name(k), k, _arrow_type(v) if v else pa.string()) for k, v in kinds.items()]
    fields += [pa.field(col, typ) for col, _, typ in columns]
    metadata = None
    if other:
        fields.append(pa.field(OTHER_FIELDS, pa.string()))
        metadata = {
            b"fleet.other_fields": f"data keys beyond the first {max_fields} of the stream "
            "(FLEET_EXPORT_PARQUET_MAX_FIELDS), as one JSON object per row".encode()
        }
    return ParquetLayout(pa.schema(fields, metadata=metadata), columns, other)


def _cell(value: Any, typ: pa.DataType) -> Any:
    if value is None:
        return None
    if pa.types.is_string(typ) and not isinstance(value, str):
        return orjson.dumps(value).decode()
    if pa.types.is_floating(typ):
        return float(value)
    return value


def write_parquet(
    engine: Engine, robots: list[str], start: float, end: float, stream: str, out: Any, max_fields: int = MAX_FIELDS
) -> int:
    """One stream as Parquet (second pass: rows in batches); returns the rows written."""
    layout = parquet_schema(engine, robots, start, end, stream, max_fields)
    schema, kept = layout.schema, {key for _, key, _ in layout.columns}
    n = 0
    with pq.ParquetWriter(out, schema, compression="zstd") as writer:
        cols: dict[str, list[Any]] = {f.name: [] for f in schema}

        def flush() -> None:
            if cols["ts"]:
                writer.write_batch(pa.RecordBatch.from_pydict(cols, schema=schema))
                for v in cols.values():
                    v.clear()

        for row in reads.iter_telemetry(engine, robots, start, end, stream):
            data = _data(row.payload)
            cols["robot_id"].append(row.robot_id)
            cols["ts"].append(row.ts)
            cols["recv_ts"].append(row.recv_ts)
            cols["seq"].append(row.seq)
            for col, key, typ in layout.columns:
                cols[col].append(_cell(data.get(key), typ))
            if layout.other:
                rest = {k: v for k, v in data.items() if k not in kept}
                cols[OTHER_FIELDS].append(orjson.dumps(rest).decode() if rest else None)
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
            write_parquet(export.engine, export.robots, start, end, stream_name, tmp, export.max_fields)
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
