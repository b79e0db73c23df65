"""Alarms: list, acknowledge, the rules' thresholds, and the admin's battery override."""

from __future__ import annotations

import asyncio
import time
from typing import Annotated, Literal

from fastapi import APIRouter, Path, Query
from starlette.concurrency import run_in_threadpool

from backend.api.deps import ADMIN, OPERATOR, VIEWER, ActorDep, AdminDep, OperatorDep, RobotDep, ServicesDep
from backend.core.alarm_rules import RULES
from backend.core.errors import ServiceError
from backend.schemas import AlarmPublic, AlarmRulePublic, AlarmRuleUpdate
from backend.services.safety.alarms import alarm_public
from backend.store import alarms as store

router = APIRouter(prefix="/api", tags=["alarms"], dependencies=[VIEWER])


@router.get("/alarms", response_model=list[AlarmPublic])
async def list_alarms(
    services: ServicesDep,
    state: Annotated[
        Literal["open", "active", "acknowledged", "cleared"] | None,
        Query(description="open = active or acknowledged; none: every alarm, newest first"),
    ] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
) -> list[AlarmPublic]:
    rows = await run_in_threadpool(store.list_alarms, services.engine, state, limit)
    return [alarm_public(r) for r in rows]


@router.post(
    "/alarms/{alarm_id}/ack",
    response_model=AlarmPublic,
    dependencies=[OPERATOR],
    responses={404: {"description": "unknown alarm (code unknown_alarm)"}},
)
async def acknowledge(
    services: ServicesDep,
    principal: OperatorDep,
    actor: ActorDep,
    alarm_id: Annotated[int, Path(ge=1, le=2**62)],
) -> AlarmPublic:
    """Someone has seen to it: ``active`` -> ``acknowledged`` (stored with who and when). A condition alarm
    clears by itself when its condition is gone; an event alarm (data lost) clears once acknowledged."""
    alarm = await services.alarms.ack(alarm_id, principal.name)
    if alarm is None:
        raise ServiceError(404, f"unknown alarm {alarm_id}", "unknown_alarm")
    services.audit.record(actor, "alarm_ack", alarm.robot_id, {"alarm": alarm_id, "kind": alarm.kind})
    return alarm


@router.get("/alarm-rules", response_model=list[AlarmRulePublic])
async def alarm_rules(services: ServicesDep) -> list[AlarmRulePublic]:
    return [
        AlarmRulePublic(
            kind=r.kind,
            severity=r.severity,
            description=r.description,
            event=r.event,
            enabled=services.alarms.enabled(r.kind),
            params=services.alarms.params(r.kind),
        )
        for r in RULES.values()
    ]


@router.put(
    "/alarm-rules",
    response_model=list[AlarmRulePublic],
    dependencies=[ADMIN],
    responses={422: {"description": "unknown rule, or a parameter that rule does not have"}},
)
async def set_alarm_rule(
    services: ServicesDep, principal: AdminDep, actor: ActorDep, body: AlarmRuleUpdate
) -> list[AlarmRulePublic]:
    """Change one rule's thresholds (only the parameters it has) or switch it off (admin, audited)."""
    # the body's schema allows only that rule's own parameters (a discriminated union on kind)
    params = {k: v for k, v in body.params.model_dump().items() if v is not None}
    values = {
        "kind": body.kind,
        "enabled": body.enabled,
        "params": params,
        "updated_at": time.time(),
        "updated_by": principal.name,
    }
    fut = services.writer.submit(store.save_rule(values), want_result=True, after_rows=False)
    assert fut is not None
    await asyncio.wrap_future(fut)
    services.alarms.rules[body.kind] = values
    services.audit.record(actor, "alarm_rule", None, {"kind": body.kind, "enabled": body.enabled, "params": params})
    return await alarm_rules(services)


@router.post(
    "/robots/{robot_id}/battery-override",
    response_model=list[AlarmPublic],
    dependencies=[ADMIN],
    responses={404: {"description": "unknown robot"}, 409: {"description": "no battery-critical alarm"}},
)
async def battery_override(robot: RobotDep, services: ServicesDep, actor: ActorDep) -> list[AlarmPublic]:
    """Let a robot with a critical battery drive again (e.g. to bring it to the edge). Audited; ends when
    the alarm clears."""
    if not await services.alarms.override_battery(robot.id, actor.name):
        raise ServiceError(409, f"{robot.id!r} has no battery-critical alarm", "no_battery_alarm")
    services.audit.record(actor, "battery_override", robot.id, {})
    return services.alarms.of_robot(robot.id)
