"""What a run's exports read, in time order and in chunks: telemetry, commands and events of the run's
robots. Each chunk is one short query on a connection taken from the pool and given back before the
chunk's rows are handed on: an export whose client is slow holds no connection and, on SQLite, no read
transaction that would keep the WAL from being checkpointed. Series are read along their indexes and
merged here, so no query sorts a whole run."""

from __future__ import annotations

import heapq
from collections.abc import Iterator
from typing import Any, NamedTuple

from sqlalchemy import Connection, Engine, bindparam, text

from backend.store.telemetry_raw import iter_raw

#: rows per chunk of an export's reads
EXPORT_CHUNK = 2000


def _after(keys: tuple[str, ...], last: tuple[Any, ...], params: dict[str, Any]) -> str:
    """``(k0, k1, ...) > (:k0, :k1, ...)`` spelled out (plus ``k0 >= :k0`` for the index)."""
    for i, value in enumerate(last):
        params[f"k{i}"] = value
    cond = f"{keys[-1]} > :k{len(keys) - 1}"
    for i in range(len(keys) - 2, -1, -1):
        cond = f"({keys[i]} > :k{i} OR ({keys[i]} = :k{i} AND {cond}))"
    return f"{keys[0]} >= :k0 AND {cond}"


def _chunked(
    engine: Engine, select_sql: str, where: str, keys: tuple[str, ...], params: dict[str, Any], batch: int
) -> Iterator[Any]:
    """The rows of ``select_sql WHERE where ORDER BY keys`` (keys unique together), one chunk per query on a
    connection given back before the chunk's rows are handed on: an export whose client is slow holds no
    connection and, on SQLite, no read transaction that would keep the WAL from being checkpointed."""
    order = ", ".join(keys)
    last: tuple[Any, ...] | None = None
    while True:
        p = dict(params)
        cond = where if last is None else f"{where} AND {_after(keys, last, p)}"
        sql = f"{select_sql} WHERE {cond} ORDER BY {order} LIMIT {batch}"
        query = text(sql).bindparams(bindparam("robots", expanding=True)) if ":robots" in sql else text(sql)
        with engine.connect() as conn:
            rows = conn.execute(query, p).all()
        yield from rows
        if len(rows) < batch:
            return
        last = tuple(getattr(rows[-1], k) for k in keys)


class Telemetry(NamedTuple):
    """A stored telemetry row as an export reads it (ordered by its first fields: time, then seq)."""

    ts: float
    seq: int
    robot_id: str
    stream: str
    recv_ts: float | None
    payload: str


def _robot_streams(conn: Connection, robot_id: str) -> list[str]:
    """The robot's streams by a loose index scan (one index probe per stream, not a scan of its rows)."""
    out: list[str] = []
    q = "SELECT stream FROM telemetry WHERE robot_id = :r{} ORDER BY stream LIMIT 1"
    row = conn.execute(text(q.format("")), {"r": robot_id}).first()
    while row is not None:
        out.append(row[0])
        row = conn.execute(text(q.format(" AND stream > :s")), {"r": robot_id, "s": row[0]}).first()
    return out


def _series(engine: Engine, robot_id: str, stream: str, start: float, end: float, batch: int) -> Iterator[Telemetry]:
    for chunk in iter_raw(engine, robot_id, stream, start, end, batch=batch):
        for ts, seq, payload, recv_ts in chunk:
            yield Telemetry(ts, seq, robot_id, stream, recv_ts, payload)


def iter_telemetry(
    engine: Engine,
    robots: list[str],
    start: float,
    end: float,
    stream: str | None = None,
    batch: int = EXPORT_CHUNK,
) -> Iterator[Telemetry]:
    """Rows of a run's robots in time order: each (robot, stream) read in chunks along its index, merged
    here (about ``batch`` rows in memory in all, at least 100 per series)."""
    if not robots:
        return
    if stream is not None:
        pairs = [(r, stream) for r in robots]
    else:
        with engine.connect() as conn:
            pairs = [(r, s) for r in robots for s in _robot_streams(conn, r)]
    per = max(100, batch // max(1, len(pairs)))
    yield from heapq.merge(*(_series(engine, r, s, start, end, per) for r, s in pairs))


def iter_commands(engine: Engine, robots: list[str], start: float, end: float) -> Iterator[Any]:
    """Commands of the run's robots in time order (each robot read along its index, merged here)."""
    per = max(100, EXPORT_CHUNK // max(1, len(robots)))
    select_sql = "SELECT id, robot_id, command, args, source, ts, ttl_s, status, reason FROM commands"
    yield from heapq.merge(
        *(
            _chunked(engine, select_sql, "robot_id = :r AND ts >= :a AND ts <= :b", ("ts", "id"), p, per)
            for p in ({"r": r, "a": start, "b": end} for r in robots)
        ),
        key=lambda row: (row.ts, row.id),
    )


def iter_events(engine: Engine, robots: list[str], start: float, end: float) -> Iterator[Any]:
    """Events of the run's robots and fleet-wide ones (e-stops...), in time order."""
    yield from _chunked(
        engine,
        "SELECT id, ts, kind, robot_id, detail FROM events",
        "ts >= :a AND ts <= :b AND (robot_id IS NULL OR robot_id IN :robots)",
        ("ts", "id"),
        {"robots": robots or [""], "a": start, "b": end},
        EXPORT_CHUNK,
    )
