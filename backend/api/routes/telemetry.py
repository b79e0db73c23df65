"""Telemetry history: one robot's stream, or several robots and streams at once; JSON, CSV or NDJSON.

Bounded by default: at most ``max_points`` points per series, downsampled in SQL when the range holds
more (the response says how: ``method``, ``bucket_s``, ``sources``; CSV/NDJSON in ``X-Fleet-*``
headers). ``raw=true`` returns stored rows as they are: JSON in pages (``limit``, ``cursor`` /
``next_cursor``), CSV/NDJSON streamed; an unbounded raw export over ``FLEET_HISTORY_EXPORT_MAX_ROWS``
rows is refused with 422 (narrow the range or page with ``limit`` + ``cursor``), and so is a ``limit`` over
it.

Readers never starve the control plane (backend/services/telemetry/readers.py): every read here uses the
readers' own database pool and threads, and a CSV/NDJSON export is admitted first (429/503 with
Retry-After when the client or the server runs its most), encoded on an export thread and cut off when its
client stops reading (backend/api/exports.py).

``time=recv_ts``: every point also carries ``recv_ts``, when the server received it (its clock), beside the
robot's ``ts`` (CSV: a ``recv_ts`` column; NDJSON: a key), so a plot can use either time base and clock
trouble shows. Ranges and order stay on the robot's ``ts``.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from typing import IO, Annotated, Any, Literal

import orjson
from fastapi import APIRouter, HTTPException, Query, Request
from sqlalchemy import Engine

from backend.api.deps import VIEWER, RobotDep, ServicesDep
from backend.api.exports import EXPORT_REFUSALS, admit, export_response, read, read_json
from backend.api.params import EndQ, StartQ, parse_range
from backend.core.errors import ServiceError
from backend.schemas import HistoryPage, HistorySet, TimeBase
from backend.services.lifecycle import Services
from backend.store.export import Bucketing, CsvEncoder, data_columns, ndjson_rows
from backend.store.telemetry_query import query_series
from backend.store.telemetry_raw import Cursor, CursorError, count_raw, iter_raw, next_cursor_after, raw_page
from fleet_protocol import STREAM_PATTERN

router = APIRouter(tags=["telemetry"], dependencies=[VIEWER])

Format = Literal["json", "csv", "ndjson"]
FIELDS_PATTERN = r"^[A-Za-z0-9_-]{1,64}(,[A-Za-z0-9_-]{1,64}){0,31}$"
#: comma-separated names (robot ids, streams; spaces and empty items ignored), or "*"
NAME_LIST_PATTERN = r"^( *\* *|[ ,]*([A-Za-z0-9_-]{1,64}( *,[ ,]*[A-Za-z0-9_-]{1,64})*)?[ ,]*)$"
MEDIA = {"csv": "text/csv; charset=utf-8", "ndjson": "application/x-ndjson"}
#: raw JSON page size (default, maximum)
PAGE_DEFAULT, PAGE_MAX = 1000, 10_000
MAX_SERIES = 200

_EXPORT_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "JSON, or with format=csv|ndjson a streamed export (X-Fleet-Method, X-Fleet-Downsampled, "
        "X-Fleet-Sources, X-Fleet-Next-Cursor headers)",
        "content": {"text/csv": {}, "application/x-ndjson": {}},
    },
    422: {"description": "bad parameters, or an unbounded raw export over the row limit"},
    **EXPORT_REFUSALS,
}

MaxPointsQ = Annotated[int, Query(ge=1, le=10000, description="points per series at most (bounded mode)")]
FieldsQ = Annotated[
    str | None,
    Query(max_length=2100, pattern=FIELDS_PATTERN, description="comma-separated data fields to keep, e.g. x,y"),
]
FormatQ = Annotated[Format, Query(description="json, or csv / ndjson (streamed)")]
RawQ = Annotated[bool, Query(description="stored rows, not downsampled (JSON paged, CSV/NDJSON streamed)")]
CommentsQ = Annotated[
    bool,
    Query(
        description="CSV: also write the description and units (X-Fleet-Description, X-Fleet-Units) as two # "
        "lines before the header row, as exports did before 2026-11-29 (read with pandas' comment='#')"
    ),
]
TimeQ = Annotated[
    TimeBase,
    Query(
        description="recv_ts: each point also carries when the server received it (server clock), for plots on "
        "that time base; downsampled reads then use raw rows only (the rollups keep no receive times). Ranges "
        "and order stay on the robot's ts"
    ),
]


def _fields(fields: str | None) -> list[str] | None:
    return fields.split(",") if fields else None


def _cursor(cursor: str | None) -> Cursor | None:
    if cursor is None:
        return None
    try:
        return Cursor.decode(cursor)
    except CursorError as exc:
        raise ServiceError(422, str(exc), "bad_cursor") from None


def _header_text(text: str) -> str:
    """An HTTP header value is ASCII: units such as m/s² are written m/s^2 there."""
    return text.replace("²", "^2").replace("³", "^3").encode("ascii", "backslashreplace").decode()


def _headers(
    pages: list[HistoryPage],
    fmt: Format,
    streams: list[str],
    next_cursor: str | None = None,
    enc: CsvEncoder | None = None,
) -> dict[str, str]:
    """X-Fleet-* (how the rows were made; a CSV's description and units) and a file name that says it too:
    ``...-raw.csv`` or ``...-bucketed.csv``."""
    bucketed = any(p.downsampled for p in pages)
    name = f"telemetry-{'-'.join(dict.fromkeys(streams))[:100]}-{'bucketed' if bucketed else 'raw'}.{fmt}"
    methods = sorted({p.method for p in pages}) or ["none"]
    sources = sorted({s for p in pages for s in p.sources}) or ["raw"]
    headers = {
        "X-Fleet-Method": ",".join(methods),
        "X-Fleet-Downsampled": "true" if bucketed else "false",
        "X-Fleet-Sources": ",".join(sources),
        "Content-Disposition": f'attachment; filename="{name}"',
    }
    if enc is not None:
        what, units = enc.description()
        headers["X-Fleet-Description"] = _header_text(what)
        headers["X-Fleet-Units"] = _header_text(units)
    if next_cursor:
        headers["X-Fleet-Next-Cursor"] = next_cursor
    return headers


def _encoder(
    pages: list[HistoryPage], fmt: Format, fields: list[str] | None, multi: bool, recv: bool, comments: bool
) -> CsvEncoder | None:
    """The CSV encoder of these pages (None for NDJSON); raw exports pass one empty page per stream."""
    if fmt != "csv":
        return None
    bucketed = any(p.downsampled for p in pages)
    streams = [p.stream for p in pages]
    bucketing = None
    if bucketed:
        widths = [p.bucket_s for p in pages if p.bucket_s]
        bucketing = Bucketing(sorted({p.method for p in pages if p.downsampled}), max(widths) if widths else None)
    return CsvEncoder(data_columns(streams, bucketed, fields), multi, streams, bucketing, recv, comments)


def _encode_pages(pages: list[HistoryPage], enc: CsvEncoder | None, recv: bool) -> Iterator[bytes]:
    if enc is None:
        for p in pages:
            yield ndjson_rows(p.robot_id, p.stream, ((pt.ts, pt.seq, pt.data, pt.recv_ts) for pt in p.points), recv)
        return
    yield enc.header()
    for p in pages:
        yield enc.rows(p.robot_id, p.stream, ((pt.ts, pt.seq, pt.data, pt.recv_ts) for pt in p.points))


def _written(chunks: Iterator[bytes]) -> Callable[[IO[bytes]], None]:
    """An export's producer: the chunks, encoded on the export thread, written to the response."""

    def produce(out: IO[bytes]) -> None:
        for chunk in chunks:
            out.write(chunk)

    return produce


def _stream_raw(
    engine: Engine,
    pairs: list[tuple[str, str]],
    start: float | None,
    end: float | None,
    cursor: Cursor | None,
    limit: int | None,
    enc: CsvEncoder | None,
    fields: list[str] | None,
    recv: bool,
) -> Iterator[bytes]:
    """Runs on an export thread while the response streams: rows read a chunk at a time (no connection held
    while the client reads). ``enc`` None: NDJSON."""
    if enc is not None:
        yield enc.header()
    keep = set(fields) if fields else None
    for robot_id, stream in pairs:
        for batch in iter_raw(engine, robot_id, stream, start, end, cursor, limit):
            points = []
            for ts, seq, payload, recv_ts in batch:
                data = orjson.loads(payload)
                if keep is not None:
                    data = {k: v for k, v in data.items() if k in keep}
                points.append((ts, seq, data, recv_ts))
            yield ndjson_rows(robot_id, stream, points, recv) if enc is None else enc.rows(robot_id, stream, points)


def _raw_pages(pairs: list[tuple[str, str]]) -> list[HistoryPage]:
    """One empty page per stream of a raw export: what its headers and columns are made from."""
    streams = list(dict.fromkeys(s for _, s in pairs)) or ["position"]
    return [HistoryPage(robot_id="", stream=st, downsampled=False, method="none", points=[]) for st in streams]


def _too_many(n: int, limit: int) -> HTTPException:
    return HTTPException(
        422,
        detail=(
            f"the range holds {n} raw rows, more than the export limit of {limit}: narrow start/end, page with "
            "limit and cursor (the next cursor comes in X-Fleet-Next-Cursor / next_cursor), or leave out "
            "raw=true for a downsampled series"
        ),
    )


def _limit_bounded(limit: int | None, services: Services) -> None:
    most = services.settings.history_export_max_rows
    if limit is not None and limit > most:
        raise HTTPException(
            422,
            detail=f"limit: a raw export page holds at most {most} rows (FLEET_HISTORY_EXPORT_MAX_ROWS); page on "
            "with the cursor in X-Fleet-Next-Cursor",
        )


@router.get("/api/robots/{robot_id}/telemetry", response_model=HistoryPage, responses=_EXPORT_RESPONSES)
async def telemetry(
    request: Request,
    robot: RobotDep,
    services: ServicesDep,
    stream: Annotated[str, Query(pattern=STREAM_PATTERN)] = "position",
    start: StartQ = None,
    end: EndQ = None,
    max_points: MaxPointsQ = 1000,
    fields: FieldsQ = None,
    format: FormatQ = "json",
    raw: RawQ = False,
    limit: Annotated[
        int | None,
        Query(
            ge=1,
            description=f"raw=true: rows per page (JSON: default {PAGE_DEFAULT}, max {PAGE_MAX}; CSV/NDJSON: max "
            "FLEET_HISTORY_EXPORT_MAX_ROWS)",
        ),
    ] = None,
    cursor: Annotated[str | None, Query(max_length=200, description="raw=true: next_cursor of the page before")] = None,
    time: TimeQ = "ts",
    comments: CommentsQ = False,
) -> Any:
    """One robot's stream in time order. Default: at most ``max_points`` points, bucketed in SQL when the range
    holds more (``method``: ``none``, ``bucket-mean-minmax`` for position, ``bucket-last`` otherwise).
    ``raw=true``: stored rows; JSON is paged (``limit``, ``cursor``), CSV/NDJSON are streamed."""
    lo, hi = parse_range(start, end)
    field_list = _fields(fields)
    cur = _cursor(cursor)
    recv = time == "recv_ts"
    engine = services.readers.engine
    if not raw:
        if cursor is not None or limit is not None:
            raise HTTPException(422, detail="limit and cursor page raw rows: add raw=true")
        if format == "json":
            return await read_json(
                services, query_series, engine, robot.id, stream, lo, hi, max_points, field_list, recv
            )
        slot = admit(services, request)
        try:
            page = await read(services, query_series, engine, robot.id, stream, lo, hi, max_points, field_list, recv)
        except BaseException:
            slot.release()
            raise
        enc = _encoder([page], format, field_list, False, recv, comments)
        return export_response(
            services,
            slot,
            _written(_encode_pages([page], enc, recv)),
            what=f"history export of {robot.id}",
            media_type=MEDIA[format],
            headers=_headers([page], format, [stream], enc=enc),
        )
    if format == "json":
        size = limit or PAGE_DEFAULT
        if size > PAGE_MAX:
            raise HTTPException(422, detail=f"limit: a JSON page holds at most {PAGE_MAX} rows")
        return await read_json(services, raw_page, engine, robot.id, stream, lo, hi, cur, size, field_list, recv)
    _limit_bounded(limit, services)

    def _check() -> str | None:
        with engine.connect() as conn:
            if limit is None:
                n = count_raw(conn, robot.id, stream, lo, hi, cur)
                if n > services.settings.history_export_max_rows:
                    raise _too_many(n, services.settings.history_export_max_rows)
                return None
            after = next_cursor_after(conn, robot.id, stream, lo, hi, cur, limit)
            return None if after is None else after.encode()

    slot = admit(services, request)
    try:
        next_cursor = await read(services, _check)
    except BaseException:
        slot.release()
        raise
    empty = _raw_pages([(robot.id, stream)])
    enc = _encoder(empty, format, field_list, False, recv, comments)
    return export_response(
        services,
        slot,
        _written(_stream_raw(engine, [(robot.id, stream)], lo, hi, cur, limit, enc, field_list, recv)),
        what=f"raw export of {robot.id}",
        media_type=MEDIA[format],
        headers=_headers(empty, format, [stream], next_cursor, enc),
    )


def _split(value: str | None, what: str) -> list[str] | None:
    if value is None or value.strip() in ("", "*"):
        return None
    items = [v.strip() for v in value.split(",") if v.strip()]
    for v in items:
        if not re.fullmatch(STREAM_PATTERN, v):
            raise HTTPException(422, detail=f"{what}: {v[:70]!r} is not a valid name")
    return list(dict.fromkeys(items))


@router.get(
    "/api/telemetry",
    response_model=HistorySet,
    responses={**_EXPORT_RESPONSES, 404: {"description": "an unknown robot in robots (code unknown_robot)"}},
)
async def telemetry_many(
    request: Request,
    services: ServicesDep,
    robots: Annotated[
        str | None,
        Query(max_length=8000, pattern=NAME_LIST_PATTERN, description="comma-separated robot ids; omitted or * = all"),
    ] = None,
    streams: Annotated[
        str, Query(max_length=2000, pattern=NAME_LIST_PATTERN, description="comma-separated streams")
    ] = "position",
    start: StartQ = None,
    end: EndQ = None,
    max_points: MaxPointsQ = 1000,
    fields: FieldsQ = None,
    format: FormatQ = "json",
    raw: Annotated[bool, Query(description="stored rows (CSV/NDJSON only), up to the export row limit")] = False,
    time: TimeQ = "ts",
    comments: CommentsQ = False,
) -> Any:
    """Several robots and streams over one range (the history page's query): one series per (robot, stream),
    each bounded by ``max_points`` like the per-robot route. CSV/NDJSON carry robot_id and stream per row.
    ``raw=true`` streams CSV or NDJSON only (raw JSON is paged per robot): with ``format=json`` it is 422
    ``raw_json``."""
    lo, hi = parse_range(start, end)
    field_list = _fields(fields)
    recv = time == "recv_ts"
    robot_ids = _split(robots, "robots")
    stream_names = _split(streams, "streams") or ["position"]
    if robot_ids is None:
        robot_ids = sorted(services.registry.robots)
    unknown = [r for r in robot_ids if services.registry.get(r) is None]
    if unknown:
        raise ServiceError(404, f"unknown robot {unknown[0]!r}", "unknown_robot")
    pairs = [(r, s) for r in robot_ids for s in stream_names]
    if len(pairs) > MAX_SERIES:
        raise HTTPException(422, detail=f"at most {MAX_SERIES} series (robots x streams) per request")
    if raw and format == "json":
        raise ServiceError(
            422, "raw JSON is paged per robot: GET /api/robots/{id}/telemetry?raw=true&limit=&cursor=", "raw_json"
        )
    engine = services.readers.engine

    def _all() -> list[HistoryPage]:
        return [query_series(engine, r, s, lo, hi, max_points, field_list, recv) for r, s in pairs]

    if format == "json":
        return await read_json(services, lambda: HistorySet(start=lo, end=hi, max_points=max_points, series=_all()))

    def _count() -> int:
        with engine.connect() as conn:
            return sum(count_raw(conn, r, s, lo, hi, None) for r, s in pairs)

    slot = admit(services, request)
    try:
        if raw:
            n = await read(services, _count)
            if n > services.settings.history_export_max_rows:
                raise _too_many(n, services.settings.history_export_max_rows)
            pages = _raw_pages(pairs)
            enc = _encoder(pages, format, field_list, True, recv, comments)
            chunks = _stream_raw(engine, pairs, lo, hi, None, None, enc, field_list, recv)
        else:
            pages = await read(services, _all)
            enc = _encoder(pages, format, field_list, True, recv, comments)
            chunks = _encode_pages(pages, enc, recv)
    except BaseException:
        slot.release()
        raise
    return export_response(
        services,
        slot,
        _written(chunks),
        what="history export",
        media_type=MEDIA[format],
        headers=_headers(pages, format, stream_names, enc=enc),
    )
