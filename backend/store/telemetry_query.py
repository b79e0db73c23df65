"""Telemetry history reads, bounded: downsampled in SQL, from raw rows and the rollup aggregates.

Bounded queries (``query_series``): when a range holds more than ``max_points`` points it is cut into
``max_points`` equal time buckets in SQL. Position keeps its shape (``bucket-mean-minmax``): per bucket
the mean of x/y/z plus their min and max (so peaks survive), the row count and the last row's yaw and
seq; ``ts`` is the mean time. Other streams (``bucket-last``): the last row of each bucket as stored.
One GROUP BY pass computes the aggregates; the last rows are then fetched by their exact time through
the (robot_id, stream, ts, x, y, z) index, so no window function sorts the range, and a raw position
GROUP BY reads that covering index alone (migration 0015).

Buckets of a second or more read the rollup tables (``backend/store/rollup.py``): whole minutes inside
the range come from ``telemetry_1s`` (buckets under a minute) or ``telemetry_1m``; the partial minutes at
the edges and minutes not rolled up yet (dirty: new or late rows) come from raw rows. Aggregates merge
into buckets exactly (counts, sums, min of mins, max of maxes), and the buckets are whole seconds or whole
minutes on the aggregates' grid (``_aligned_buckets``), so the result equals a raw GROUP BY. Where retention deleted the
raw rows, the sealed aggregates stand in for them. ``sources`` says what answered.

``recv`` (``time=recv_ts``): each point also carries when the server received it (a bucket: the mean of its
rows' ``recv_ts``, or the last row's for ``bucket-last``). The aggregates keep no receive times, so such a
read uses raw rows only: slower over long ranges, and empty where retention removed the raw rows.

Raw reads (pages, exports) are in ``backend/store/telemetry_raw.py``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import orjson
from sqlalchemy import Connection, Engine, bindparam, text

from backend.schemas import HistoryPage, Source, TelemetryPoint
from backend.store.minutes import minute_sql
from backend.store.rollup import dirty_minutes
from backend.store.telemetry_raw import filter_fields, range_sql

AXES = ("x", "y", "z")
#: the IN list of one last-row lookup
_IN_CHUNK = 2000


# ---------------------------------------------------------------------------------------------------
# SQL helpers
# ---------------------------------------------------------------------------------------------------


def _bucket_sql(dialect: str, col: str) -> str:
    # col >= :lo, so truncation (SQLite CAST) equals floor; PostgreSQL's CAST rounds, hence floor() there.
    if dialect == "postgresql":
        return f"CAST(floor(({col} - :lo) / :w) AS BIGINT)"
    return f"CAST(({col} - :lo) / :w AS INTEGER)"


def _minute_floor(ts: float) -> float:
    return math.floor(ts / 60.0) * 60.0


def _minute_ceil(ts: float) -> float:
    return math.ceil(ts / 60.0) * 60.0


def _aligned_buckets(lo: float, hi: float, max_points: int, res: float) -> tuple[float, float]:
    """Buckets on the aggregates' grid: the first starts on a whole ``res`` (a second or a minute) and each
    is a whole number of them wide, so every aggregate row (one second or one minute of rows) falls inside
    one bucket, the same bucket its rows would. Without this, a row whose minute straddled a bucket's edge
    went whole into the bucket of its first row, and a read answered differently before and after the
    rollup worker had passed. At most ``max_points`` buckets still cover [lo, hi]."""
    start = math.floor(lo / res) * res
    width = math.ceil(max(hi - start, 1e-6) / max_points * (1 + 1e-9) / res) * res
    return start, width


@dataclass
class _Plan:
    """Which aggregate table, and which minutes it answers for (the rest comes from raw rows)."""

    res: str | None  # "1s" / "1m"; None: raw rows only
    sealed_only: bool  # short range: only sealed aggregates (raw rows are gone there) stand in for raw
    a: float | None  # interior [a, b): whole minutes inside the range
    b: float | None
    dirty: list[float]  # dirty minutes in the interior: raw rows answer for them


def _in_list(name: str, values: list[float], params: dict[str, Any]) -> str:
    """``(:name_0, :name_1, ...)`` - literal bind names, so the same params dict serves several statements."""
    keys = []
    for i, v in enumerate(values):
        params[f"{name}_{i}"] = v
        keys.append(f":{name}_{i}")
    return "(" + ", ".join(keys) + ")"


def _agg_filter(dialect: str, plan: _Plan, start: float | None, end: float | None, params: dict[str, Any]) -> str:
    """WHERE for the aggregate rows a series uses: overlapping the range, and sealed or a clean interior minute."""
    sql = " AND robot_id = :robot_id AND stream = :stream"
    if start is not None:
        params["start"], params["astart"] = start, start - 60.0
        sql += " AND bucket_ts >= :astart AND last_ts >= :start"
    if end is not None:
        params["end"] = end
        sql += " AND bucket_ts <= :end"
    if plan.sealed_only:
        return sql + " AND sealed"
    interior = []
    if plan.a is not None:
        params["ia"] = plan.a
        interior.append("bucket_ts >= :ia")
    if plan.b is not None:
        params["ib"] = plan.b
        interior.append("bucket_ts < :ib")
    if plan.dirty:
        interior.append(f"{minute_sql(dialect, 'bucket_ts')} NOT IN {_in_list('dm', plan.dirty, params)}")
    return sql + (f" AND (sealed OR ({' AND '.join(interior)}))" if interior else "")


def _raw_segments(plan: _Plan, start: float | None, end: float | None) -> list[tuple[float | None, float | None, bool]]:
    """The time ranges raw rows answer for, as (lo, hi, hi inclusive): the whole range, or next to the
    aggregates only the partial minutes at the edges and the dirty minutes (merged into runs). Separate
    ranges, not one OR, so each is an index range scan."""
    if plan.res is None or plan.sealed_only:
        return [(start, end, True)]
    segments: list[tuple[float | None, float | None, bool]] = []
    if plan.a is not None and start is not None and start < plan.a:
        segments.append((start, plan.a, False))
    run: list[float] = []
    for m in sorted(plan.dirty):
        if run and m == run[-1] + 60.0:
            run.append(m)
            continue
        if run:
            segments.append((run[0], run[-1] + 60.0, False))
        run = [m]
    if run:
        segments.append((run[0], run[-1] + 60.0, False))
    if plan.b is not None and end is not None and plan.b <= end:
        segments.append((plan.b, end, True))
    return segments


def _raw_parts(columns: str, plan: _Plan, start: float | None, end: float | None, params: dict[str, Any]) -> list[str]:
    parts = []
    for i, (lo, hi, inclusive) in enumerate(_raw_segments(plan, start, end)):
        cond = ""
        if lo is not None:
            params[f"rs{i}"] = lo
            cond += f" AND ts >= :rs{i}"
        if hi is not None:
            params[f"re{i}"] = hi
            cond += f" AND ts {'<=' if inclusive else '<'} :re{i}"
        parts.append(f"SELECT {columns} FROM telemetry WHERE robot_id = :robot_id AND stream = :stream{cond}")
    return parts


# ---------------------------------------------------------------------------------------------------
# Bounded (downsampled) series
# ---------------------------------------------------------------------------------------------------


def query_series(
    engine: Engine,
    robot_id: str,
    stream: str,
    start: float | None,
    end: float | None,
    max_points: int,
    fields: Sequence[str] | None = None,
    recv: bool = False,
) -> HistoryPage:
    with engine.connect() as conn:
        return series(conn, robot_id, stream, start, end, max_points, fields, recv)


def series(
    conn: Connection,
    robot_id: str,
    stream: str,
    start: float | None,
    end: float | None,
    max_points: int,
    fields: Sequence[str] | None = None,
    recv: bool = False,
) -> HistoryPage:
    dialect = conn.dialect.name
    key = {"robot_id": robot_id, "stream": stream}
    field_list = list(fields) if fields else None
    params = dict(key)
    rng = range_sql("ts", start, end, params)
    # two subqueries: SQLite answers a lone min() or max() from the index, both at once by scanning the range
    where = f"FROM telemetry WHERE robot_id = :robot_id AND stream = :stream{rng}"
    raw_lo, raw_hi = conn.execute(text(f"SELECT (SELECT min(ts) {where}), (SELECT max(ts) {where})"), params).one()
    aparams = dict(key)
    agg_any = _Plan("1m", True, None, None, [])
    agg_lo, agg_hi, sealed_n = (
        (None, None, 0)
        if recv  # raw rows only: the aggregates have no receive times
        else conn.execute(
            text(
                "SELECT min(first_ts), max(last_ts), count(*) FROM telemetry_1m WHERE true"
                + _agg_filter(dialect, agg_any, start, end, aparams)
            ),
            aparams,
        ).one()
    )
    los = [v for v in (raw_lo, agg_lo) if v is not None]
    his = [v for v in (raw_hi, agg_hi) if v is not None]
    empty = HistoryPage(
        robot_id=robot_id, stream=stream, downsampled=False, method="none", points=[], fields=field_list, sources=[]
    )
    if not los:
        return empty
    lo, hi = float(min(los)), float(max(his))
    width = max(hi - lo, 1e-6) / max_points * (1 + 1e-9) + 1e-12

    if width < 1.0:  # a short range: raw rows (and sealed per-second aggregates where raw rows are gone)
        plan = _Plan("1s", True, None, None, []) if sealed_n else _Plan(None, False, None, None, [])
        if plan.res is None:
            n = conn.execute(
                text(
                    "SELECT count(*) FROM (SELECT 1 FROM telemetry WHERE robot_id = :robot_id AND stream = :stream"
                    f"{rng} LIMIT :cap) AS c"
                ),
                {**params, "cap": max_points + 1},
            ).scalar_one()
            if n <= max_points:
                rows = conn.execute(
                    text(
                        "SELECT ts, seq, payload, recv_ts FROM telemetry WHERE robot_id = :robot_id"
                        f" AND stream = :stream{rng} ORDER BY ts, seq LIMIT :limit"
                    ),
                    {**params, "limit": max_points},
                ).all()
                points = [
                    _point(r[0], r[1], filter_fields(orjson.loads(r[2]), field_list, False), recv, r[3]) for r in rows
                ]
                return HistoryPage(
                    robot_id=robot_id, stream=stream, downsampled=False, method="none", points=points, fields=field_list
                )
    else:
        a = None if start is None else _minute_ceil(start)
        b = None if end is None else _minute_floor(end)
        dirty = dirty_minutes(conn, robot_id, stream, a if a is not None else 0.0, b if b is not None else math.inf)
        plan = _Plan("1m" if width >= 60.0 else "1s", False, a, b, dirty)
        lo, width = _aligned_buckets(lo, hi, max_points, 60.0 if plan.res == "1m" else 1.0)
        if recv:
            plan = _Plan(None, False, None, None, [])

    position = stream == "position"
    groups = _bucket_groups(conn, key, start, end, lo, width, position, plan, recv)
    last = _last_rows(conn, key, start, end, [g["last_ts"] for g in groups], position, plan)
    points = []
    for g in groups:
        seq, yaw, payload, last_recv = last.get(g["last_ts"], (0, None, "{}", None))
        if position:
            data: dict[str, Any] = {"count": int(g["n"])}
            for axis in AXES:
                xyz_n = g["xyz_n"]
                s = g[f"{axis}_sum"]
                data[axis] = None if s is None or not xyz_n else float(s) / float(xyz_n)
                for suffix in ("_min", "_max"):
                    v = g[f"{axis}{suffix}"]
                    data[axis + suffix] = None if v is None else float(v)
            data["yaw"] = yaw
            ts = float(g["ts_sum"]) / float(g["n"])
            recv_ts = float(g["recv_sum"]) / float(g["recv_n"]) if recv and g["recv_n"] else None
        else:
            data = orjson.loads(payload)
            ts = float(g["last_ts"])
            recv_ts = last_recv
        points.append(_point(ts, int(seq), filter_fields(data, field_list, position), recv, recv_ts))
    sources: list[Source] = ["raw"] if any(g["raw_n"] for g in groups) else []
    if any(g["n"] > g["raw_n"] for g in groups):
        sources.append("1m" if plan.res == "1m" else "1s")
    return HistoryPage(
        robot_id=robot_id,
        stream=stream,
        downsampled=True,
        method="bucket-mean-minmax" if position else "bucket-last",
        points=points,
        sources=sources,
        bucket_s=width,
        fields=field_list,
    )


def _point(ts: float, seq: int, data: dict[str, Any], recv: bool, recv_ts: float | None) -> TelemetryPoint:
    if recv:
        return TelemetryPoint(ts=ts, seq=seq, data=data, recv_ts=recv_ts)
    return TelemetryPoint(ts=ts, seq=seq, data=data)


def _bucket_groups(
    conn: Connection,
    key: dict[str, Any],
    start: float | None,
    end: float | None,
    lo: float,
    width: float,
    position: bool,
    plan: _Plan,
    recv: bool = False,
) -> list[dict[str, Any]]:
    dialect = conn.dialect.name
    params: dict[str, Any] = {**key, "lo": lo, "w": width}
    if plan.res is None:  # raw only: one plain GROUP BY
        axis = "".join(f", sum({a}) AS {a}_sum, min({a}) AS {a}_min, max({a}) AS {a}_max" for a in AXES)
        if recv:
            axis += ", sum(recv_ts) AS recv_sum, count(recv_ts) AS recv_n"
        sql = (
            f"SELECT {_bucket_sql(dialect, 'ts')} AS b, count(*) AS n, count(*) AS raw_n, sum(ts) AS ts_sum, "
            f"max(ts) AS last_ts{axis if position else ''}{', count(x) AS xyz_n' if position else ''} "
            f"FROM telemetry WHERE robot_id = :robot_id AND stream = :stream{range_sql('ts', start, end, params)} "
            "GROUP BY b ORDER BY b"
        )
    else:
        agg_where = _agg_filter(dialect, plan, start, end, params)
        raw_axis = "".join(f", {a} AS {a}_sum, {a} AS {a}_min, {a} AS {a}_max" for a in AXES)
        agg_axis = "".join(f", {a}_sum, {a}_min, {a}_max" for a in AXES)
        raw_cols = (
            f"{_bucket_sql(dialect, 'ts')} AS b, 1 AS n, 1 AS raw_n, ts AS ts_sum, ts AS last_ts{raw_axis}, "
            "CASE WHEN x IS NULL THEN 0 ELSE 1 END AS xyz_n"
        )
        agg_part = (
            f"SELECT {_bucket_sql(dialect, 'first_ts')} AS b, n, 0 AS raw_n, ts_sum, last_ts{agg_axis}, xyz_n "
            f"FROM telemetry_{plan.res} WHERE true{agg_where}"
        )
        union = " UNION ALL ".join([*_raw_parts(raw_cols, plan, start, end, params), agg_part])
        axis = "".join(f", sum({a}_sum) AS {a}_sum, min({a}_min) AS {a}_min, max({a}_max) AS {a}_max" for a in AXES)
        sql = (
            f"SELECT b, sum(n) AS n, sum(raw_n) AS raw_n, sum(ts_sum) AS ts_sum, max(last_ts) AS last_ts{axis}, "
            f"sum(xyz_n) AS xyz_n FROM ({union}) AS u GROUP BY b ORDER BY b"
        )
    return [dict(r._mapping) for r in conn.execute(text(sql), params)]


def _last_rows(
    conn: Connection,
    key: dict[str, Any],
    start: float | None,
    end: float | None,
    times: list[float],
    position: bool,
    plan: _Plan,
) -> dict[float, tuple[int, float | None, str, float | None]]:
    """ts -> (seq, yaw, payload, recv_ts) of the last row at each bucket's last time: raw rows by exact time
    through the (robot_id, stream, ts, ...) index, aggregate rows by their last_ts (no receive time)."""
    out: dict[float, tuple[int, float | None, str, float | None]] = {}
    what = "yaw, '{}'" if position else "NULL, payload"
    dialect = conn.dialect.name
    queries = [
        f"SELECT ts, seq, {what}, recv_ts FROM telemetry WHERE robot_id = :robot_id AND stream = :stream AND ts IN :tss"
    ]
    params = dict(key)
    if plan.res is not None:
        awhere = _agg_filter(dialect, plan, start, end, params)
        queries.append(
            f"SELECT last_ts, last_seq, {what}, NULL FROM telemetry_{plan.res} WHERE last_ts IN :tss{awhere}"
        )
    for sql in queries:
        stmt = text(sql).bindparams(bindparam("tss", expanding=True))
        for i in range(0, len(times), _IN_CHUNK):
            for ts, seq, yaw, payload, recv_ts in conn.execute(stmt, {**params, "tss": times[i : i + _IN_CHUNK]}):
                prev = out.get(ts)
                if prev is None or seq > prev[0]:
                    out[ts] = (int(seq), yaw, payload, recv_ts)
    return out
