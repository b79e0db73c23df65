"""WebSocket /ws: subscribe to robots and streams; receive batched JSON-array frames."""

from __future__ import annotations

import asyncio
import contextlib
import logging

import orjson
from fastapi import APIRouter, WebSocket
from pydantic import ValidationError
from starlette.websockets import WebSocketDisconnect

from backend.api.deps import WS_VIEWER, WsServicesDep, close_held, held_socket
from backend.core.security import Role
from backend.schemas import Subscribe
from backend.services.access.sockets import HeldSocket
from backend.services.lifecycle import Services
from backend.services.live.hub import LiveClient

log = logging.getLogger(__name__)
router = APIRouter(tags=["live"], dependencies=[WS_VIEWER])  # checked before accept; 1008 otherwise

MAX_CLIENT_MESSAGE = 64 * 1024


def _snapshot(services: Services, client: LiveClient) -> bytes:
    """The robots, the e-stop, and the live missions with their swept areas (the map draws them at once)."""
    robots = services.registry.all_public(client.robots)
    return orjson.dumps(
        {
            "type": "snapshot",
            "robots": [r.model_dump(mode="json") for r in robots],
            "estop": services.estop.state.model_dump(mode="json"),
            **services.missions.live_snapshot(),
        }
    )


def _retained(services: Services, client: LiveClient) -> list[bytes]:
    """The latest message of each retained stream (base-station geometry) the client subscribed to."""
    out = []
    for st in services.registry.robots.values():
        if not client.wants_robot(st.id):
            continue
        for stream, (ts, seq, data) in st.retained.items():
            if client.wants_stream(stream):
                out.append(
                    orjson.dumps(
                        {"type": "telemetry", "robot_id": st.id, "stream": stream, "ts": ts, "seq": seq, "data": data}
                    )
                )
    return out


def _error(detail: str) -> bytes:
    return orjson.dumps({"type": "error", "detail": detail})


async def _receive(websocket: WebSocket, client: LiveClient, services: Services, held: HeldSocket) -> None:
    while True:
        message = await websocket.receive()
        if message["type"] == "websocket.disconnect" or held.denied is not None:
            return
        raw = message.get("text") or message.get("bytes") or b""
        if len(raw) > MAX_CLIENT_MESSAGE:
            client.offer_control(_error("message too large"))
            continue
        try:
            sub = Subscribe.model_validate(orjson.loads(raw))
        except (orjson.JSONDecodeError, ValidationError) as exc:
            client.offer_control(
                _error(f'expected {{"type": "subscribe", "robots": [...], "streams": [...]}}: {str(exc)[:200]}')
            )
            continue
        client.subscribe(sub.robots, sub.streams)
        client.offer_control(_snapshot(services, client))
        for retained in _retained(services, client):
            client.offer_control(retained)


@router.websocket("/ws")
async def live(websocket: WebSocket, services: WsServicesDep) -> None:
    """Client sends {"type": "subscribe", "robots": ["*"|ids], "streams": ["*"|names]}; each server frame is a
    JSON array of snapshot/robot/telemetry/command/estop messages."""
    await websocket.accept()
    with held_socket(websocket, Role.VIEWER) as held:
        client = services.hub.add(websocket.send_text)
        tasks = {
            asyncio.create_task(client.run(), name="ws-send"),
            asyncio.create_task(_receive(websocket, client, services, held), name="ws-recv"),
            asyncio.create_task(held.wait_denied(), name="ws-denied"),
        }
        try:
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for task in done:
                exc = task.exception()
                if exc is not None and not isinstance(exc, WebSocketDisconnect | ConnectionError | RuntimeError):
                    log.warning("websocket closed after error: %r", exc)
        finally:
            services.hub.remove(client)
            for task in tasks:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
            await close_held(websocket, held, 1013 if client.too_slow else 1000)
