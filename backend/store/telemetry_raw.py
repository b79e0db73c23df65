"""Telemetry history reads, raw: stored rows as they are, ordered by (ts, seq), in pages (``raw_page``)
or streamed for exports (``iter_raw``), from an optional cursor (the first row not yet returned). Also the
SQL pieces the bounded reads (``backend/store/telemetry_query.py``) share: the time range and the fields
kept."""

from __future__ import annotations

import base64
import binascii
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import orjson
from sqlalchemy import Connection, Engine, text

from backend.schemas import HistoryPage, TelemetryPoint


class CursorError(ValueError):
    pass


@dataclass(frozen=True, slots=True)
class Cursor:
    """The first (ts, seq) a raw read returns."""

    ts: float
    seq: int

    def encode(self) -> str:
        return base64.urlsafe_b64encode(f"{self.ts!r},{self.seq}".encode()).decode().rstrip("=")

    @classmethod
    def decode(cls, value: str) -> Cursor:
        try:
            raw = base64.urlsafe_b64decode(value + "=" * (-len(value) % 4)).decode()
            ts, seq = raw.split(",")
            return cls(float(ts), int(seq))
        except (ValueError, binascii.Error, UnicodeDecodeError):
            raise CursorError(f"cursor {value[:40]!r} is not one this server returned") from None


def range_sql(col: str, start: float | None, end: float | None, params: dict[str, Any]) -> str:
    parts = []
    if start is not None:
        parts.append(f"{col} >= :start")
        params["start"] = start
    if end is not None:
        parts.append(f"{col} <= :end")
        params["end"] = end
    return "".join(f" AND {p}" for p in parts)


def _where(start: float | None, end: float | None, cursor: Cursor | None, params: dict[str, Any]) -> str:
    """The range and the cursor, with one lower bound on ts: given two (``ts >= :start AND ts >= :cts``),
    SQLite starts its index scan at the first, so each page of a long export scanned every row before it."""
    if cursor is None:
        return range_sql("ts", start, end, params)
    params["cts"], params["cseq"] = cursor.ts, cursor.seq
    lower = cursor.ts if start is None else max(start, cursor.ts)
    return range_sql("ts", lower, end, params) + " AND (ts > :cts OR seq >= :cseq)"


def filter_fields(data: dict[str, Any], fields: Sequence[str] | None, bucketed: bool) -> dict[str, Any]:
    if not fields:
        return data
    keep = set(fields)
    if bucketed:
        keep |= {f"{f}_min" for f in fields} | {f"{f}_max" for f in fields} | {"count"}
    return {k: v for k, v in data.items() if k in keep}


def count_raw(
    conn: Connection, robot_id: str, stream: str, start: float | None, end: float | None, cursor: Cursor | None
) -> int:
    params: dict[str, Any] = {"robot_id": robot_id, "stream": stream}
    where = _where(start, end, cursor, params)
    return int(
        conn.execute(
            text(f"SELECT count(*) FROM telemetry WHERE robot_id = :robot_id AND stream = :stream{where}"), params
        ).scalar_one()
    )


def _raw_select(
    robot_id: str, stream: str, start: float | None, end: float | None, cursor: Cursor | None
) -> tuple[str, dict[str, Any]]:
    params: dict[str, Any] = {"robot_id": robot_id, "stream": stream}
    where = _where(start, end, cursor, params)
    return (
        f"SELECT ts, seq, payload, recv_ts FROM telemetry WHERE robot_id = :robot_id AND stream = :stream{where} "
        "ORDER BY ts, seq",
        params,
    )


def next_cursor_after(
    conn: Connection,
    robot_id: str,
    stream: str,
    start: float | None,
    end: float | None,
    cursor: Cursor | None,
    limit: int,
) -> Cursor | None:
    """The cursor of the row after the first ``limit`` rows (None: there is none)."""
    sql, params = _raw_select(robot_id, stream, start, end, cursor)
    row = conn.execute(text(sql + " LIMIT 1 OFFSET :offset"), {**params, "offset": limit}).first()
    return None if row is None else Cursor(float(row[0]), int(row[1]))


def raw_page(
    engine: Engine,
    robot_id: str,
    stream: str,
    start: float | None,
    end: float | None,
    cursor: Cursor | None,
    limit: int,
    fields: Sequence[str] | None = None,
    recv: bool = False,
) -> HistoryPage:
    """A page of stored rows; ``recv``: each point carries its ``recv_ts`` (``time=recv_ts``)."""
    sql, params = _raw_select(robot_id, stream, start, end, cursor)
    with engine.connect() as conn:
        rows = conn.execute(text(sql + " LIMIT :limit"), {**params, "limit": limit + 1}).all()
    more = rows[limit] if len(rows) > limit else None
    field_list = list(fields) if fields else None
    points = [
        TelemetryPoint(ts=r[0], seq=r[1], data=filter_fields(orjson.loads(r[2]), field_list, False), recv_ts=r[3])
        if recv
        else TelemetryPoint(ts=r[0], seq=r[1], data=filter_fields(orjson.loads(r[2]), field_list, False))
        for r in rows[:limit]
    ]
    return HistoryPage(
        robot_id=robot_id,
        stream=stream,
        downsampled=False,
        method="none",
        points=points,
        fields=field_list,
        next_cursor=None if more is None else Cursor(float(more[0]), int(more[1])).encode(),
    )


def iter_raw(
    engine: Engine,
    robot_id: str,
    stream: str,
    start: float | None,
    end: float | None,
    cursor: Cursor | None = None,
    limit: int | None = None,
    batch: int = 2000,
) -> Iterator[list[tuple[float, int, str, float | None]]]:
    """Stored rows (ts, seq, payload, recv_ts) in batches, constant memory for any export size. Each batch
    is one short query on a connection taken from the pool and given back before the batch is handed on
    (the next starts after the last row: (ts, seq) is unique in a series): a client that stops reading
    holds no connection and, on SQLite, no read transaction that would keep the WAL from being
    checkpointed."""
    left = limit
    while left is None or left > 0:
        size = batch if left is None else min(batch, left)
        sql, params = _raw_select(robot_id, stream, start, end, cursor)
        with engine.connect() as conn:
            rows = conn.execute(text(sql + " LIMIT :limit"), {**params, "limit": size}).all()
        if not rows:
            return
        yield [(float(r[0]), int(r[1]), r[2], None if r[3] is None else float(r[3])) for r in rows]
        if len(rows) < size:
            return
        if left is not None:
            left -= len(rows)
        last = rows[-1]
        cursor = Cursor(float(last[0]), int(last[1]) + 1)
