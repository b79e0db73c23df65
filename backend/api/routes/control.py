"""WebSocket /ws/control/{robot_id}: an off-board controller's one socket for poses in and set-points out.

The server sends JSON-array frames as on ``/ws`` (the robot's ``position`` stream, or the streams named in
``?streams=``, of the robot and of the robots in ``?watch=``, plus their robot/command/estop messages),
starting with a ``ready`` message. The client sends one JSON object per message:
``{"type": "drive", "linear": m/s, "angular": rad/s, "duration_s": deadman, "ref": any}`` or
``{"type": "stop", "ref": any}``; each is answered with ``{"type": "sent", "ref", "id", "command", "ts"}``
once published, or ``{"type": "error", "ref", "code", "detail"}`` (the codes of POST .../commands).
Closing the socket stops the robot if it may still be running on one of its set-points. The socket is
closed (1008, with the reason) as soon as its token is revoked, its user disabled or demoted below operator,
or its session logged out; the lease it held is released then.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Annotated, Any

import orjson
from fastapi import APIRouter, Query, WebSocket
from starlette.websockets import WebSocketDisconnect

from backend.api.deps import WS_OPERATOR, WsServicesDep, close_held, held_socket
from backend.core.security import AUTH_OFF_PRINCIPAL, Principal, Role
from backend.services.access.audit import Actor
from backend.services.access.sockets import HeldSocket
from backend.services.control.sessions import ControlSession
from backend.services.lifecycle import Services
from backend.services.live.hub import LiveClient

log = logging.getLogger(__name__)
router = APIRouter(tags=["live"], dependencies=[WS_OPERATOR])  # checked before accept; 1008 otherwise

MAX_WATCH = 50


def _actor(websocket: WebSocket, client_id: str) -> Actor:
    """As ``get_actor`` for HTTP: with authentication off the lease holder is the client's own id."""
    principal: Principal = getattr(websocket.state, "principal", AUTH_OFF_PRINCIPAL)
    host = websocket.client.host if websocket.client else ""
    holder = ""
    if principal is AUTH_OFF_PRINCIPAL:
        tab = (client_id or websocket.headers.get("x-fleet-client") or "").strip()[:64]
        holder = f"client:{tab}" if tab else ""
    return Actor(
        subject=principal.subject,
        name=principal.name if not holder else f"{principal.name} {holder}",
        token_id=principal.token_id,
        client=host,
        holder=holder,
    )


def _csv(text: str, limit: int) -> list[str]:
    return [part.strip()[:64] for part in text.split(",") if part.strip()][:limit]


async def _receive(websocket: WebSocket, session: ControlSession, held: HeldSocket) -> None:
    while True:
        message = await websocket.receive()
        if message["type"] == "websocket.disconnect" or held.denied is not None:  # not one set-point more
            return
        await session.handle(message.get("text") or message.get("bytes") or b"")


#: command statuses a controller hears of: refusals (a geofence, an expired set-point) and ended goals
TOLD_STATUSES = frozenset({"rejected", "expired", "failed", "aborted", "timeout"})


def _worth_sending(message: dict[str, Any]) -> bool:
    """Every robot/estop message, but of commands only refusals and ended goals: each set-point is
    accepted and then done when the next one replaces it, three messages per set-point for nothing."""
    if message.get("type") != "command":
        return True
    cmd = message.get("command") or {}
    return cmd.get("status") in TOLD_STATUSES or cmd.get("command") not in ("drive", "stop")


def _ready(services: Services, robot_id: str, client: LiveClient) -> bytes:
    robots = services.registry.all_public(client.robots)
    return orjson.dumps(
        {
            "type": "ready",
            "robot_id": robot_id,
            "robots": [r.model_dump(mode="json") for r in robots],
            "estop": services.estop.state.model_dump(mode="json"),
        }
    )


@router.websocket("/ws/control/{robot_id}")
async def control(
    websocket: WebSocket,
    robot_id: str,
    services: WsServicesDep,
    watch: Annotated[str, Query(max_length=4000, description="other robots whose streams to receive")] = "",
    streams: Annotated[str, Query(max_length=2000, description="streams to receive (default position)")] = "",
    client: Annotated[str, Query(max_length=64, description="client id (the lease holder with auth off)")] = "",
) -> None:
    """Drive one robot with velocity set-points and receive its live poses (needs the operator role)."""
    await websocket.accept()
    if services.registry.get(robot_id) is None:
        detail = f"unknown robot {robot_id[:64]!r}"
        await websocket.send_text(
            orjson.dumps([{"type": "error", "ref": None, "code": "unknown_robot", "detail": detail}]).decode()
        )
        await websocket.close(code=1008, reason="unknown robot")
        return
    actor = _actor(websocket, client)
    with held_socket(websocket, Role.OPERATOR) as held:
        await _drive(websocket, robot_id, services, actor, held, watch=watch, streams=streams, client=client)


async def _drive(
    websocket: WebSocket,
    robot_id: str,
    services: Services,
    actor: Actor,
    held: HeldSocket,
    *,
    watch: str,
    streams: str,
    client: str,
) -> None:
    """The socket's life: set-points in, poses out, until it closes or its principal may no longer drive."""
    auth = websocket.app.state.auth
    live = services.hub.add(websocket.send_text)
    live.subscribe([robot_id, *_csv(watch, MAX_WATCH)], _csv(streams, 20) or ["position"])
    live.control_filter = _worth_sending
    session = ControlSession(
        robot_id=robot_id,
        actor=actor,
        commands=services.commands,
        reply=live.offer_control,
        take_rate=lambda: auth.commands.take((actor.subject, robot_id)),
        source="control" + (f" {client[:40]}" if client else ""),
    )
    live.offer_control(_ready(services, robot_id, live))
    tasks = {
        asyncio.create_task(live.run(), name="control-send"),
        asyncio.create_task(_receive(websocket, session, held), name="control-recv"),
        asyncio.create_task(held.wait_denied(), name="control-denied"),
    }
    try:
        done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for task in done:
            exc = task.exception()
            if exc is not None and not isinstance(exc, WebSocketDisconnect | ConnectionError | RuntimeError):
                log.warning("control socket of %s closed after error: %r", robot_id[:64], exc)
    finally:
        services.hub.remove(live)
        for task in tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        await session.close()
        if held.denied is not None:  # they may no longer drive: the lease they held goes too
            with contextlib.suppress(Exception):
                await services.leases.release_all_of(actor, why=held.denied)
        await close_held(websocket, held, 1013 if live.too_slow else 1000)
