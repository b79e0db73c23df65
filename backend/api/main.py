"""All API routers."""

from fastapi import APIRouter

from backend.api.routes import (
    auth,
    camera,
    commands,
    estop,
    events,
    health,
    metrics,
    robots,
    telemetry,
    tokens,
    ui,
    users,
    ws,
)

api_router = APIRouter()
for module in (health, auth, tokens, users, metrics, robots, commands, estop, events, telemetry, camera, ws, ui):
    api_router.include_router(module.router)
