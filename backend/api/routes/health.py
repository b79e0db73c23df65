"""Liveness/health and ingest statistics."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from starlette.concurrency import run_in_threadpool

from backend import __version__
from backend.api.deps import PUBLIC, VIEWER, AuthDep, OptionalPrincipalDep, ServicesDep
from backend.core.security import Role
from backend.schemas import DatabaseHealth, HealthPublic, MqttHealth
from backend.store import repository as repo

router = APIRouter(prefix="/api", tags=["health"])


@router.get("/health", response_model=HealthPublic, dependencies=[PUBLIC])
async def health(services: ServicesDep, auth: AuthDep, principal: OptionalPrincipalDep) -> HealthPublic:
    """Public: status, version, whether authentication is on and the links are up. Details (URLs,
    reject counters) only for authenticated callers who may read (viewers and up: not a metrics token)."""
    db_ok = await run_in_threadpool(repo.ping, services.engine)
    connected = services.bridge.connected
    details = principal is not None and principal.allows(Role.VIEWER)
    return HealthPublic(
        status="ok" if db_ok and connected else "degraded",
        version=__version__,
        auth="on" if auth.enabled else "off",
        mqtt=MqttHealth(url=services.settings.mqtt_url_redacted if details else None, connected=connected),
        database=DatabaseHealth(url=services.settings.database_url_redacted if details else None, ok=db_ok),
        rejects=services.rejects.snapshot() if details else None,
    )


@router.get("/stats", dependencies=[VIEWER])
async def stats(services: ServicesDep) -> dict[str, Any]:
    """Counters for operators: refused input, MQTT inbox, DB writer, live hub, per-robot seq gaps, and the
    e-stop's and holds' checks against the broker, the fleet poses (``acl_problem``: robots may not hear them)."""
    return {
        "rejects": services.rejects.snapshot(),
        "mqtt": services.bridge.stats(),
        "writer": services.writer.stats(),
        "ws": services.hub.stats(),
        "camera": services.camera.stats(),
        "event_loop": services.watchdog.stats(),
        # CPU work kept off the event loop: mission plans (and coverage pictures), password checks
        "pools": {"planner": services.missions.planner.stats(), "passwords": services.passwords.stats()},
        "commands": {
            "unknown_acks": services.commands.unknown_acks,
            "ack_retries_refused": services.commands.ack_retries_refused,
        },
        "streams": {
            rid: {name: vars(s) for name, s in st.streams.items()} for rid, st in services.registry.robots.items()
        },
        "gap_repair": services.repair.stats() if services.repair is not None else {},
        # history reads and exports: running, refused (per client, all busy), cut off for not reading
        "exports": services.readers.stats(),
        # broker (re)connections checked for a lost e-stop or hold, and the latches put back (safety/latches.py)
        "latches": {
            "synced": services.latches.synced if services.latches is not None else 0,
            "put_back": services.latches.latches_put_back if services.latches is not None else 0,
        },
        # the fleet poses published (fleet/poses.py) and whether the broker's ACL lets robots hear them
        "poses": services.poses.stats() if services.poses is not None else {},
    }
