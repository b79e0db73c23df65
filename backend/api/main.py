"""All API routers."""

from fastapi import APIRouter

from backend.api.routes import (
    alarms,
    audit,
    auth,
    camera,
    commands,
    control,
    enrol,
    estop,
    events,
    health,
    holds,
    leases,
    legacy,
    metrics,
    missions,
    rehearsal,
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
    legacy,
    leases,
    audit,
    commands,
    enrol,
    estop,
    events,
    missions,
    rehearsal,
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
