"""Commands to robots and their acks."""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from backend.api.deps import OPERATOR, VIEWER, ActorDep, AuthDep, OperatorDep, RobotDep, ServicesDep
from backend.api.params import EndQ, StartQ, parse_range
from backend.core.errors import ServiceError
from backend.schemas import CommandCreate, CommandPublic
from backend.services.site.service import GOAL_COMMANDS
from backend.store import repository as repo
from fleet_protocol import MAX_GOAL_TIMEOUT_S

log = logging.getLogger(__name__)
router = APIRouter(prefix="/api", tags=["commands"], dependencies=[VIEWER])

#: ``?wait`` for a command that is not a goal: its ack comes at once or not at all
MAX_WAIT_S = 10.0


@router.post(
    "/robots/{robot_id}/commands",
    response_model=CommandPublic,
    dependencies=[OPERATOR],
    status_code=202,
    responses={
        200: {"model": CommandPublic, "description": "with ?wait: the final ack, or the latest ack status"},
        404: {"description": "unknown robot"},
        409: {
            "description": "robot offline, fleet e-stop engaged, robot held, or driven by someone else "
            "(another operator's control lease)"
        },
        503: {"description": "server not connected to the MQTT broker"},
        422: {
            "description": "command not in the robot's capabilities (code unsupported_command), bad args "
            "(bad_args), a goal outside the site's geofence (geofence), a goal to a robot on the old "
            "framework (unsupported_by_legacy), a wait over 10 s for a command that is not a goal "
            "(wait_too_long); nothing was sent"
        },
        429: {"description": "over this user's command rate for this robot (see Retry-After); not sent"},
        504: {"model": CommandPublic, "description": "with ?wait: no ack at all in time (status timeout)"},
    },
)
async def send_command(
    robot_id: str,
    body: CommandCreate,
    services: ServicesDep,
    principal: OperatorDep,
    auth: AuthDep,
    actor: ActorDep,
    wait: Annotated[
        float | None,
        Query(
            gt=0,
            le=MAX_GOAL_TIMEOUT_S,
            description="seconds to wait for a final ack: up to 3600 for goto/follow_path (their timeout), "
            "at most 10 for every other command (more: 422 wait_too_long)",
        ),
    ] = None,
) -> JSONResponse:
    """Send a command. Without ``wait``: 202 once published. With ``wait=S``: waits up to S s for a final
    ack (done/rejected/expired) → 200; if only an earlier ack (e.g. accepted) came → 200 with that status;
    no ack at all → 504 with status ``timeout``. A goal (goto, follow_path) acks ``done``/``failed``/
    ``aborted`` when it ends, so its ``wait`` may be as long as its timeout. Goals are checked against the
    site's geofence first (422 ``geofence``); a goto into another robot's body is refused (422
    ``goal_inside_robot``). Needs the operator role; rate-limited per caller and robot."""
    retry = auth.commands.take((principal.subject, robot_id))
    if retry > 0:
        raise HTTPException(
            429,
            detail=f"too many commands to {robot_id[:64]!r}; slow down",
            headers={"Retry-After": auth.commands.retry_after_header(retry)},
        )
    log.info(
        "command %s to %s by %s",
        body.command,
        robot_id[:64],
        principal.subject,
        extra={"robot_id": robot_id[:64], "client": principal.subject},
    )
    if wait is not None and wait > MAX_WAIT_S and body.command not in GOAL_COMMANDS and services.registry.get(robot_id):
        raise ServiceError(
            422, f"wait is at most {MAX_WAIT_S:g} s for {body.command!r} (longer only for goals)", "wait_too_long"
        )
    try:
        cmd = await services.commands.create(robot_id, body, actor)
        code = 202
        if wait is not None:
            cmd, code = await services.commands.wait(cmd.id, wait)
    except ServiceError as exc:
        raise exc from None  # the app's handler answers it (detail and code)
    return JSONResponse(cmd.model_dump(mode="json"), status_code=code)


@router.get("/robots/{robot_id}/commands", response_model=list[CommandPublic])
async def list_commands(
    robot: RobotDep,
    services: ServicesDep,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    start: StartQ = None,
    end: EndQ = None,
) -> list[CommandPublic]:
    """Newest first. ``start``/``end`` as ISO 8601 or epoch seconds."""
    lo, hi = parse_range(start, end)
    rows = await run_in_threadpool(repo.list_commands, services.engine, robot.id, limit, lo, hi)
    return services.commands.overlay(rows, robot.id, lo, hi, limit)


@router.get("/commands/{command_id}", response_model=CommandPublic, responses={404: {"description": "unknown"}})
async def get_command(command_id: str, services: ServicesDep) -> CommandPublic:
    cmd = services.commands.cached(command_id)
    if cmd is None:
        cmd = await run_in_threadpool(repo.get_command, services.engine, command_id)
    if cmd is None:
        raise ServiceError(404, f"unknown command {command_id!r}", "unknown_command")
    return cmd
