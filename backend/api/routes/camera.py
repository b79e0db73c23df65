"""Live camera: the latest JPEG over REST, and a WebSocket per robot that pushes frames, newest wins."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re

from fastapi import APIRouter, HTTPException, WebSocket
from fastapi.responses import Response
from starlette.websockets import WebSocketDisconnect

from backend.api.deps import VIEWER, WS_VIEWER, RobotDep, ServicesDep, WsServicesDep, close_held, held_socket
from backend.core.security import Role
from fleet_protocol import ROBOT_ID_PATTERN

log = logging.getLogger(__name__)
router = APIRouter(tags=["camera"])


@router.get(
    "/api/robots/{robot_id}/camera/latest.jpg",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}}, 404: {"description": "no frame received yet"}},
    dependencies=[VIEWER],
)
async def latest_frame(robot: RobotDep, services: ServicesDep) -> Response:
    """The robot's most recent camera frame; ``X-Frame-Seq`` ties it to the ``apriltag`` stream."""
    frame = services.camera.latest(robot.id)
    if frame is None:
        raise HTTPException(404, detail=f"no camera frame from robot {robot.id!r} since the server started")
    return Response(
        frame.jpeg,
        media_type="image/jpeg",
        headers={
            "Cache-Control": "no-store",
            "X-Frame-Seq": str(frame.header.frame_seq),
            "X-Frame-Ts": repr(frame.header.ts),
            "X-Frame-Age-Ms": f"{max(0.0, frame.received - frame.header.ts) * 1000:.1f}",
        },
    )


@router.websocket("/ws/camera/{robot_id}", dependencies=[WS_VIEWER])  # checked before accept
async def camera_feed(websocket: WebSocket, robot_id: str, services: WsServicesDep) -> None:
    """Binary messages, each one frame exactly as the robot published it (``MFC1`` header + JPEG, see
    docs/protocol.md). A slow viewer gets the newest frame, never a queue of old ones."""
    await websocket.accept()
    if not re.fullmatch(ROBOT_ID_PATTERN, robot_id):
        await websocket.close(code=1008, reason="bad robot id")
        return
    with held_socket(websocket, Role.VIEWER) as held:
        viewer = services.camera.add_viewer(robot_id)

        async def pump() -> None:
            while True:
                frame = await viewer.next_frame()
                await websocket.send_bytes(frame.payload)

        async def drain() -> None:  # notice the close; clients have nothing to say on this socket
            while (await websocket.receive())["type"] != "websocket.disconnect":
                pass

        tasks = {
            asyncio.create_task(pump(), name=f"camera-{robot_id}"),
            asyncio.create_task(drain(), name=f"camera-recv-{robot_id}"),
            asyncio.create_task(held.wait_denied(), name=f"camera-denied-{robot_id}"),
        }
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            services.camera.remove_viewer(viewer)
            for task in tasks:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, Exception):
                    await task
            await close_held(websocket, held, 1000)
