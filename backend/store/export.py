"""CSV and NDJSON encodings of telemetry points (streamed by the history routes).

A CSV starts with its header row, so that every reader takes it as it is (Python's ``csv.DictReader``,
spreadsheets, DuckDB, pandas without options). What the rows are (the stored points, or BUCKETED with the
bucket width) and the unit of every column (from ``fleet_protocol.units``) travel in HTTP headers
(``description``, ``units``); with ``comments`` the same two lines also precede the header as ``#``
comments (``pandas.read_csv(f, comment="#")``), the form exports had before 2026-11-29.

CSV cells: floats as ``repr`` (they read back to the identical double), ints as digits, empty for null,
JSON for objects/lists. Columns: ``[robot_id, stream,] ts, time_utc, seq`` (``ts`` in epoch seconds,
``time_utc`` the same instant in ISO 8601 UTC to the microsecond; with ``time=recv_ts`` a ``recv_ts``
column follows ``seq``: when the server received the row, on its clock) then the data columns: the requested
``fields`` (bucketed position: ``count`` and each field's mean/min/max), else position's
``x, y, z, yaw`` (bucketed: ``count, x, x_min, x_max, ... yaw``), else imu's ``accel[0..2], gyro[0..2]``,
else one ``data`` column holding the data object as JSON.
"""

from __future__ import annotations

import csv
import functools
import io
import math
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import orjson

from fleet_protocol.units import STREAM_UNITS, TIME_UNIT, unit_of

POSITION_RAW = ["x", "y", "z", "yaw"]
POSITION_BUCKETED = ["count", *[f"{a}{s}" for a in ("x", "y", "z") for s in ("", "_min", "_max")], "yaw"]
#: streams of a fixed shape get a column per number (``name[i]``: item i of the list ``name``)
FLAT_COLUMNS: dict[str, list[str]] = {"imu": [f"{v}[{i}]" for v in ("accel", "gyro") for i in range(3)]}
_INDEXED = re.compile(r"^([A-Za-z0-9_-]+)\[(\d+)\]$")

#: one exported point: (ts, seq, data, recv_ts); recv_ts is written only when the export asks for it
Point = tuple[float, int, dict[str, Any], float | None]


def data_columns(streams: Sequence[str], bucketed: bool, fields: Sequence[str] | None) -> list[str]:
    position = bool(streams) and all(s == "position" for s in streams)
    if fields:
        if bucketed and position:
            return ["count", *[f"{f}{s}" for f in fields for s in ("", "_min", "_max")]]
        return list(fields)
    if position:
        return POSITION_BUCKETED if bucketed else POSITION_RAW
    if streams and len(set(streams)) == 1 and streams[0] in FLAT_COLUMNS:
        return list(FLAT_COLUMNS[streams[0]])
    return ["data"]


def _item(v: Any, i: int) -> Any:
    return v[i] if isinstance(v, list) and i < len(v) else None


def _getter(column: str) -> Callable[[dict[str, Any]], str]:
    """How a column's cell is read from a data object (once per column, not per row)."""
    if column == "data":
        return lambda d: orjson.dumps(d).decode()
    m = _INDEXED.match(column)
    if m:
        key, i = m[1], int(m[2])
        return lambda d: cell(_item(d.get(key), i))
    return lambda d: cell(d.get(column))


def cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, int | str):
        return str(v)
    return orjson.dumps(v).decode()


@dataclass(frozen=True)
class Bucketing:
    """How a downsampled export was made (None when the rows are the stored points)."""

    methods: list[str]
    #: the widest bucket of the series, seconds
    bucket_s: float | None


def _describe_bucketing(b: Bucketing) -> str:
    width = f"{b.bucket_s:.6g} s" if b.bucket_s else "time"
    parts = []
    if "bucket-mean-minmax" in b.methods:
        parts.append(
            f"position rows are {width} buckets: mean time and mean x/y/z with their min and max (*_min, *_max) "
            "and the row count; yaw and seq of the bucket's last row"
        )
    if "bucket-last" in b.methods:
        parts.append(f"other streams give the last stored row of each {width} bucket")
    how = "; ".join(parts) or f"{width} buckets"
    return f"BUCKETED (downsampled), NOT the stored points: {how}. Export raw=true for every stored point."


def comment_lines(
    streams: Sequence[str], columns: Sequence[str], bucketing: Bucketing | None, recv: bool = False
) -> list[str]:
    """The ``#`` lines before the header: what the rows are, and the unit of each column."""
    what = _describe_bucketing(bucketing) if bucketing else "the stored points (raw), every row as stored."
    units = [f"ts = {TIME_UNIT}", "time_utc = ISO 8601 UTC"]
    if recv:
        units[0] += " (robot clock)"
        units.append(f"recv_ts = {TIME_UNIT} (server clock: when the server received the row; empty: unknown)")
    names = list(dict.fromkeys(streams))
    for c in columns:
        if c == "data":
            for s in names:
                table = STREAM_UNITS.get(s)
                if table:
                    listed = ", ".join(f"{k} = {v}" for k, v in table.items() if v)
                    units.append(f"data of {s}: {listed}")
        elif c == "count":
            units.append("count = stored rows in the bucket")
        else:
            found = {u for u in (unit_of(s, c) for s in names) if u is not None}
            if len(found) == 1:
                units.append(f"{c} = {found.pop() or 'dimensionless'}")
    return [
        f"# Mollusca Fleet telemetry export of {', '.join(names) or 'no stream'}: {what}",
        "# units: " + "; ".join(units),
    ]


@functools.lru_cache(maxsize=4096)
def _second_utc(sec: int) -> str:
    return datetime.fromtimestamp(sec, tz=UTC).strftime("%Y-%m-%dT%H:%M:%S")


def iso_utc(ts: float) -> str:
    """``2026-11-25T09:27:01.123456Z``: the epoch seconds as ISO 8601 UTC, to the microsecond, rounded as
    ``datetime.fromtimestamp`` rounds. The whole second's text is cached (rows come in time order): a
    datetime per row would cost a third of the export's speed."""
    frac, whole = math.modf(ts)
    us = round(frac * 1e6)
    if us >= 1_000_000:
        whole, us = whole + 1, us - 1_000_000
    elif us < 0:
        whole, us = whole - 1, us + 1_000_000
    return f"{_second_utc(int(whole))}.{us:06d}Z"


class CsvEncoder:
    def __init__(
        self,
        columns: list[str],
        multi: bool,
        streams: Sequence[str] = (),
        bucketing: Bucketing | None = None,
        recv: bool = False,
        comments: bool = False,
    ) -> None:
        self.columns = columns
        self.recv = recv
        self.comments = comments
        self._cells = [_getter(c) for c in columns]
        self.multi = multi
        self.streams = list(streams)
        self.bucketing = bucketing
        self._buf = io.StringIO()
        self._w = csv.writer(self._buf, lineterminator="\n")

    def _take(self) -> bytes:
        out = self._buf.getvalue().encode()
        self._buf.seek(0)
        self._buf.truncate()
        return out

    def description(self) -> tuple[str, str]:
        """(what the rows are, the unit of each column): the text of the two comment lines, without ``# ``."""
        what, units = comment_lines(self.streams, self.columns, self.bucketing, self.recv)
        return what.removeprefix("# "), units.removeprefix("# units: ")

    def header(self) -> bytes:
        """The header row; with ``comments`` first the description's two ``#`` lines."""
        lines = comment_lines(self.streams, self.columns, self.bucketing, self.recv) if self.comments else []
        comments = "".join(f"{line}\n" for line in lines)
        prefix = ["robot_id", "stream"] if self.multi else []
        self._w.writerow([*prefix, "ts", "time_utc", "seq", *(["recv_ts"] if self.recv else []), *self.columns])
        return comments.encode() + self._take()

    def rows(self, robot_id: str, stream: str, points: Iterable[Point]) -> bytes:
        prefix = [robot_id, stream] if self.multi else []
        for ts, seq, data, recv_ts in points:
            cells = [get(data) for get in self._cells]
            if self.recv:
                cells.insert(0, cell(recv_ts))
            self._w.writerow([*prefix, repr(float(ts)), iso_utc(ts), str(seq), *cells])
        return self._take()


def ndjson_rows(robot_id: str, stream: str, points: Iterable[Point], recv: bool = False) -> bytes:
    if recv:
        return b"".join(
            orjson.dumps({"robot_id": robot_id, "stream": stream, "ts": ts, "seq": seq, "recv_ts": r, "data": data})
            + b"\n"
            for ts, seq, data, r in points
        )
    return b"".join(
        orjson.dumps({"robot_id": robot_id, "stream": stream, "ts": ts, "seq": seq, "data": data}) + b"\n"
        for ts, seq, data, _ in points
    )
