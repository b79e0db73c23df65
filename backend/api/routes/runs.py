"""Experiment runs (docs/runs.md): start, stop, find, annotate, delete, and export one in a piece."""

from __future__ import annotations

import base64
import time
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from backend.api.deps import ADMIN, OPERATOR, VIEWER, ActorDep, ServicesDep
from backend.api.exports import EXPORT_REFUSALS, admit, export_response, read
from backend.api.params import TIME_PATTERN, parse_time
from backend.api.routes.site import site_public
from backend.api.separation import DEFAULT_MIN_SEPARATION_M, separation_of
from backend.core.errors import ServiceError
from backend.schemas import (
    MarkerCreate,
    MarkerPublic,
    RunCreate,
    RunDetail,
    RunFrame,
    RunFrameTimes,
    RunPublic,
    RunSummary,
    RunUpdate,
)
from backend.services.lifecycle import Services
from backend.services.runs.recorder import marker_public, run_public
from backend.store import runs as store
from fleet_protocol import ROBOT_ID_PATTERN

router = APIRouter(prefix="/api/runs", tags=["runs"], dependencies=[VIEWER])

RunIdP = Annotated[int, Path(ge=1, le=2**62, description="the run's id")]
UNKNOWN_RUN: dict[int | str, dict[str, Any]] = {404: {"description": "unknown run (code unknown_run)"}}

EXPORTS: dict[str, tuple[str, str]] = {
    "mcap": ("application/octet-stream", "mcap"),
    "parquet": ("application/zip", "parquet.zip"),
    "zip": ("application/zip", "zip"),
}


@router.post(
    "",
    response_model=RunPublic,
    status_code=201,
    dependencies=[OPERATOR],
    responses={
        404: {"description": "an unknown robot in robots (code unknown_robot)"},
        409: {"description": "robots not given and no robot is online (code no_robots)"},
    },
)
async def start_run(services: ServicesDep, actor: ActorDep, body: RunCreate) -> RunPublic:
    """Start recording a run of the given robots (default: every robot online now). The caller is its
    operator; the site version and each agent's version and capabilities are kept with it. Audited as
    ``run_start``."""
    site = await services.site.latest()
    return await services.runs.start(actor, body, site.version)


@router.get("", response_model=list[RunPublic])
async def list_runs(
    services: ServicesDep,
    name: Annotated[str | None, Query(max_length=200, description="part of the name (any case)")] = None,
    tag: Annotated[str | None, Query(max_length=64, description="runs with this tag")] = None,
    robot: Annotated[str | None, Query(max_length=64, description="runs that recorded this robot")] = None,
    running: Annotated[bool | None, Query(description="only running (true) or ended (false) runs")] = None,
    before_id: Annotated[int | None, Query(ge=1, le=2**62, description="page: runs older than this id")] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
) -> list[RunPublic]:
    """Runs, newest first, found by name, tag or robot."""
    rows = await run_in_threadpool(
        store.list_runs,
        services.engine,
        name=name,
        tag=tag,
        robot=robot,
        running=running,
        before_id=before_id,
        limit=limit,
    )
    return [run_public(r) for r in rows]


@router.get("/{run_id}", response_model=RunDetail, responses=UNKNOWN_RUN)
async def get_run(services: ServicesDep, run_id: RunIdP) -> RunDetail:
    """A run with its markers and its summary: duration, message counts per stream, distance per robot,
    commands, e-stops and alarms during it, the seq gaps in what is stored, and how close the robots came
    and how often their safety filters stepped in (``separation``; a running run: up to now)."""
    row = await services.runs.get_row(run_id)
    now = time.time()
    summary = RunSummary.model_validate(await read(services, store.summary, services.readers.engine, row, now))
    end = float(row["ended_at"]) if row["ended_at"] is not None else now
    site = (await services.site.at(int(row["site_version"]))).site  # the site the run was recorded at
    min_sep = site.min_separation_m if site is not None else DEFAULT_MIN_SEPARATION_M
    summary.separation = await separation_of(services, list(row["robots"]), float(row["started_at"]), end, min_sep)
    markers = await run_in_threadpool(store.list_markers, services.engine, run_id)
    return RunDetail(
        **run_public(row).model_dump(),
        summary=summary,
        markers=[marker_public(m) for m in markers],
    )


@router.patch("/{run_id}", response_model=RunPublic, dependencies=[OPERATOR], responses=UNKNOWN_RUN)
async def update_run(services: ServicesDep, actor: ActorDep, run_id: RunIdP, body: RunUpdate) -> RunPublic:
    """Rename a run, or change its notes or tags (during it or after); audited as ``run_update``."""
    return await services.runs.update(actor, run_id, body)


@router.post(
    "/{run_id}/stop",
    response_model=RunPublic,
    dependencies=[OPERATOR],
    responses={**UNKNOWN_RUN, 409: {"description": "the run has already ended (code run_ended)"}},
)
async def stop_run(services: ServicesDep, actor: ActorDep, run_id: RunIdP) -> RunPublic:
    """End a run (also one left open by a server that crashed); audited as ``run_stop``."""
    return await services.runs.stop(actor, run_id)


@router.delete("/{run_id}", status_code=204, response_class=Response, dependencies=[ADMIN], responses=UNKNOWN_RUN)
async def delete_run(services: ServicesDep, actor: ActorDep, run_id: RunIdP) -> Response:
    """Delete a run, its markers and its camera frames (admin, audited). Telemetry, commands and events
    stay: they belong to the robots, and the raw-telemetry retention applies to them."""
    await services.runs.delete(actor, run_id)
    return Response(status_code=204)


@router.post(
    "/{run_id}/markers",
    response_model=MarkerPublic,
    status_code=201,
    dependencies=[OPERATOR],
    responses={
        **UNKNOWN_RUN,
        409: {
            "description": "a time outside the run (code marker_outside_run) or a robot not in it (code "
            "robot_not_in_run)"
        },
    },
)
async def add_marker(services: ServicesDep, actor: ActorDep, run_id: RunIdP, body: MarkerCreate) -> MarkerPublic:
    """Mark a moment of the run ("tag 3 fell"), by default now; it also shows in the event list."""
    return await services.runs.add_marker(actor, run_id, body)


@router.get("/{run_id}/markers", response_model=list[MarkerPublic], responses=UNKNOWN_RUN)
async def list_markers(services: ServicesDep, run_id: RunIdP) -> list[MarkerPublic]:
    await services.runs.get_row(run_id)
    rows = await run_in_threadpool(store.list_markers, services.engine, run_id)
    return [marker_public(m) for m in rows]


@router.get(
    "/{run_id}/frames",
    response_model=RunFrame,
    responses={
        404: {
            "description": "unknown run (code unknown_run), or no frame of that robot at or before ``at`` (code "
            "no_frame)"
        },
        422: {"description": "robot not in the run (code robot_not_in_run), at outside it (code at_outside_run)"},
        200: {
            "description": "the frame with its detections as JSON (format=json), or the JPEG itself (format=jpeg; "
            "X-Fleet-Frame-Ts, X-Fleet-Frame-Seq say which frame it is)",
            "content": {"application/json": {}, "image/jpeg": {}},
        },
    },
)
async def run_frame(
    services: ServicesDep,
    run_id: RunIdP,
    robot: Annotated[str, Query(pattern=ROBOT_ID_PATTERN, description="a robot of the run")],
    at: Annotated[str, Query(pattern=TIME_PATTERN, max_length=40, description="epoch seconds or ISO 8601")],
    format: Annotated[Literal["json", "jpeg"], Query(description="json (with detections) or jpeg")] = "json",
) -> Any:
    """The replay's camera: the robot's stored frame nearest at or before ``at`` (its own clock, as the
    frames are stamped), with the AprilTag detections of that frame."""
    row = await services.runs.get_row(run_id)
    ts = parse_time(at, "at")
    if ts is None:
        raise ServiceError(422, "at: a time is required (epoch seconds or ISO 8601)", "at_required")
    if robot not in (row["robots"] or []):
        raise ServiceError(422, f"robot: {robot!r} is not in run {run_id}", "robot_not_in_run")
    run_end = row["ended_at"] if row["ended_at"] is not None else time.time()
    if not row["started_at"] <= ts <= run_end:
        still = " (now: still recording)" if row["ended_at"] is None else ""
        raise ServiceError(
            422,
            f"at: {ts:.3f} is outside run {run_id} ({row['started_at']:.3f} .. {run_end:.3f}{still})",
            "at_outside_run",
        )
    frame = await run_in_threadpool(services.runs.frames.frame_at, run_id, robot, ts)
    jpeg = None if frame is None else await run_in_threadpool(_read, frame.path)
    if frame is None or jpeg is None:
        raise ServiceError(404, f"no camera frame of {robot} in run {run_id} at or before {ts:.3f}", "no_frame")
    if format == "jpeg":
        headers = {"X-Fleet-Frame-Ts": repr(frame.ts), "X-Fleet-Frame-Seq": str(frame.frame_seq)}
        return Response(jpeg, media_type="image/jpeg", headers=headers)
    detections = await run_in_threadpool(store.detections_of_frame, services.engine, robot, frame.ts, frame.frame_seq)
    return RunFrame(
        robot_id=robot,
        ts=frame.ts,
        frame_seq=frame.frame_seq,
        detections=detections,
        jpeg_base64=base64.b64encode(jpeg).decode(),
    )


@router.get(
    "/{run_id}/frames/times",
    response_model=RunFrameTimes,
    responses={
        404: {"description": "unknown run (code unknown_run)"},
        422: {"description": "robot not in the run (code robot_not_in_run)"},
    },
)
async def run_frame_times(
    services: ServicesDep,
    run_id: RunIdP,
    robot: Annotated[str, Query(pattern=ROBOT_ID_PATTERN, description="a robot of the run")],
) -> RunFrameTimes:
    """When each of the robot's stored frames of the run was taken (none: an empty list): the replay knows
    which frame a moment shows, and asks for it only when it changes."""
    row = await services.runs.get_row(run_id)
    if robot not in (row["robots"] or []):
        raise ServiceError(422, f"robot: {robot!r} is not in run {run_id}", "robot_not_in_run")
    times = await run_in_threadpool(services.runs.frames.frame_times, run_id, robot)
    return RunFrameTimes(robot_id=robot, frames=times)


def _read(path: Any) -> bytes | None:
    """A frame's bytes; None when it went meanwhile (the run deleted under the request)."""
    try:
        return bytes(path.read_bytes())
    except OSError:
        return None


@router.get(
    "/{run_id}/export",
    response_class=StreamingResponse,
    responses={
        **UNKNOWN_RUN,
        **EXPORT_REFUSALS,
        422: {
            "description": "from or to outside the run (codes from_outside_run, to_outside_run), or from not "
            "before to (code from_not_before_to)"
        },
        200: {
            "description": "the run, streamed: MCAP, a zip of Parquet files (one per stream), or a zip of both "
            "with run.json and the camera JPEGs. X-Fleet-Run-Running: true when the run was still recording "
            "(the export holds it up to now); X-Fleet-Expected-Bytes: an estimate of the size, for progress; "
            "X-Fleet-Range: the exported stretch (from,to)",
            "content": {"application/octet-stream": {}, "application/zip": {}},
        },
    },
)
async def export_run(
    request: Request,
    services: ServicesDep,
    run_id: RunIdP,
    format: Annotated[Literal["mcap", "parquet", "zip"], Query(description="mcap, parquet or zip")] = "mcap",
    from_: Annotated[
        str | None,
        Query(
            alias="from",
            pattern=TIME_PATTERN,
            max_length=40,
            description="export from this time on (epoch seconds or ISO 8601; default: the run's start)",
        ),
    ] = None,
    to: Annotated[
        str | None,
        Query(
            pattern=TIME_PATTERN,
            max_length=40,
            description="export up to this time (epoch seconds or ISO 8601; default: the run's end, or now)",
        ),
    ] = None,
) -> StreamingResponse:
    """Everything of the run in one download, for Foxglove / Lichtblick (MCAP), pandas, polars, DuckDB
    (Parquet), or all of it (zip); ``from`` / ``to`` export a range of it (within the run, from < to)."""
    # imported on first use: pyarrow, protobuf and the Foxglove schemas need not slow every server start
    from backend.services.runs import export as run_export

    row = await services.runs.get_row(run_id)
    now = time.time()
    run_end = row["ended_at"] if row["ended_at"] is not None else now
    start, end = export_range(row, run_end, parse_time(from_, "from"), parse_time(to, "to"))
    slot = admit(services, request)
    try:
        export, frames, frame_bytes = await _prepare(services, run_export, row, start, end, now)
    except BaseException:
        slot.release()
        raise
    writers = {"mcap": run_export.write_mcap, "parquet": run_export.write_parquet_zip, "zip": run_export.write_bundle}
    media, ext = EXPORTS[format]
    whole = max(1e-9, run_end - row["started_at"])
    part = min(1.0, (end - start) / whole)  # a range: its share of the run, for the estimate
    expected = int(_estimate(export.summary, frame_bytes if format != "parquet" else 0, format) * part)
    ranged = start > row["started_at"] or end < run_end
    name = f"run-{run_id}" + (f"-{start - row['started_at']:.1f}s-{end - row['started_at']:.1f}s" if ranged else "")
    headers = {
        "Content-Disposition": f'attachment; filename="{name}.{ext}"',
        "X-Fleet-Range": f"{start!r},{end!r}",
        "X-Fleet-Run-Running": "true" if row["ended_at"] is None else "false",
        "X-Fleet-Expected-Bytes": str(expected),
        "X-Fleet-Frames": str(frames),
    }
    write = writers[format]
    return export_response(
        services, slot, lambda out: write(export, out), what=f"run {run_id} export", media_type=media, headers=headers
    )


async def _prepare(
    services: Services, run_export: Any, row: dict[str, Any], start: float, end: float, now: float
) -> tuple[Any, int, int]:
    """What a run export needs before it streams (read on the readers' pool): the export, the run's frames
    and their bytes."""
    engine = services.readers.engine
    summary = await read(services, store.summary, engine, row, now)
    markers = [m for m in await read(services, store.list_markers, engine, row["id"]) if start <= m["ts"] <= end]
    # the site as it was when the run started (the version it recorded), not as it is now
    site = site_public(await services.site.at(row["site_version"])).model_dump(mode="json")
    export = run_export.RunExport(
        engine=engine,
        frames=services.runs.frames,
        run=row,
        markers=markers,
        summary=summary,
        site=site,
        end=end,
        start=start,
        max_fields=services.settings.export_parquet_max_fields,
    )
    frames, frame_bytes = await run_in_threadpool(services.runs.frames.usage, row["id"])
    return export, frames, frame_bytes


def export_range(row: dict[str, Any], run_end: float, from_: float | None, to: float | None) -> tuple[float, float]:
    """The exported stretch: within the run (a running run: up to now), from before to; 422 otherwise."""
    started = float(row["started_at"])
    start = started if from_ is None else from_
    end = run_end if to is None else to
    still = " (now: still recording)" if row["ended_at"] is None else ""
    limits = f"run {row['id']} spans {started:.3f} .. {run_end:.3f}{still}"
    if not started <= start <= run_end:
        raise ServiceError(422, f"from: {start:.3f} is outside the run ({limits})", "from_outside_run")
    if not started <= end <= run_end:
        raise ServiceError(422, f"to: {end:.3f} is outside the run ({limits})", "to_outside_run")
    if not start < end:
        raise ServiceError(422, f"from ({start:.3f}) must be before to ({end:.3f})", "from_not_before_to")
    return start, end


def _estimate(summary: dict[str, Any], frame_bytes: int, format: str) -> int:
    """A rough size for a progress bar (compressed telemetry is about 40 bytes a message)."""
    per_message = {"mcap": 40, "parquet": 20, "zip": 60}[format]
    return int(summary["messages_total"] * per_message + frame_bytes)
