"""All API routers."""

from fastapi import APIRouter

from backend.api.routes import (
    alarms,
    audit,
    auth,
    camera,
    commands,
    control,
    estop,
    events,
    health,
    holds,
    leases,
    metrics,
    missions,
    robots,
    runs,
    site,
    telemetry,
    tokens,
    ui,
    users,
    ws,
)

api_router = APIRouter()
ROUTERS = (
    health,
    alarms,
    auth,
    tokens,
    users,
    metrics,
    robots,
    holds,
    leases,
    audit,
    commands,
    estop,
    events,
    missions,
    telemetry,
    site,
    camera,
    runs,
    ws,
    control,
    ui,
)
for module in ROUTERS:
    api_router.include_router(module.router)
