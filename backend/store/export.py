"""CSV and NDJSON encodings of telemetry points (streamed by the history routes).

CSV cells: floats as ``repr`` (they read back to the identical double), ints as digits, empty for null,
JSON for objects/lists. Columns: ``[robot_id, stream,] ts, seq`` then the data columns: the requested
``fields`` (bucketed position: ``count`` and each field's mean/min/max), else position's
``x, y, z, yaw`` (bucketed: ``count, x, x_min, x_max, ... yaw``), else one ``data`` column holding the
data object as JSON.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Sequence
from typing import Any

import orjson

POSITION_RAW = ["x", "y", "z", "yaw"]
POSITION_BUCKETED = ["count", *[f"{a}{s}" for a in ("x", "y", "z") for s in ("", "_min", "_max")], "yaw"]


def data_columns(streams: Sequence[str], bucketed: bool, fields: Sequence[str] | None) -> list[str]:
    position = bool(streams) and all(s == "position" for s in streams)
    if fields:
        if bucketed and position:
            return ["count", *[f"{f}{s}" for f in fields for s in ("", "_min", "_max")]]
        return list(fields)
    if position:
        return POSITION_BUCKETED if bucketed else POSITION_RAW
    return ["data"]


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


class CsvEncoder:
    def __init__(self, columns: list[str], multi: bool) -> None:
        self.columns = columns
        self.multi = multi
        self._buf = io.StringIO()
        self._w = csv.writer(self._buf, lineterminator="\n")

    def _take(self) -> bytes:
        out = self._buf.getvalue().encode()
        self._buf.seek(0)
        self._buf.truncate()
        return out

    def header(self) -> bytes:
        self._w.writerow([*(["robot_id", "stream"] if self.multi else []), "ts", "seq", *self.columns])
        return self._take()

    def rows(self, robot_id: str, stream: str, points: Iterable[tuple[float, int, dict[str, Any]]]) -> bytes:
        prefix = [robot_id, stream] if self.multi else []
        for ts, seq, data in points:
            cells = [orjson.dumps(data).decode() if c == "data" else cell(data.get(c)) for c in self.columns]
            self._w.writerow([*prefix, repr(float(ts)), str(seq), *cells])
        return self._take()


def ndjson_rows(robot_id: str, stream: str, points: Iterable[tuple[float, int, dict[str, Any]]]) -> bytes:
    return b"".join(
        orjson.dumps({"robot_id": robot_id, "stream": stream, "ts": ts, "seq": seq, "data": data}) + b"\n"
        for ts, seq, data in points
    )
