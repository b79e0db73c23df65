"""``POST /api/enrol``: a robot exchanges its single-use enrolment token (``fleet-server robots add ID``) for
its broker password and the base station's pin (the fleet key, and the broker's CA when it uses TLS).

Public: the token is the credential (256 random bits, hashed at rest, expiring, used once). Limited per
address before the database is asked; every use and every refusal of a real token is logged and audited.
"""

from __future__ import annotations

import logging
import time

from fastapi import APIRouter, HTTPException, Request, Response
from starlette.concurrency import run_in_threadpool

from backend.api.deps import PUBLIC, ServicesDep
from backend.core.errors import ServiceError
from backend.core.fleet_key import fleet_key
from backend.core.security import TokenBuckets
from backend.schemas.enrolment import EnrolAnswer, EnrolRequest
from backend.services.access.audit import Actor
from backend.store.enrolments import EnrolmentRefused, redeem
from fleet_common.ratelimit import RateLimitedLogger

router = APIRouter(prefix="/api", tags=["robots"])
log = logging.getLogger("backend.enrol")
refused_log = RateLimitedLogger(log)
#: tries per address: a robot needs one; a typo or two more are fine, guessing is pointless anyway
_per_address = TokenBuckets(rate_per_s=0.1, burst=10)


@router.post(
    "/enrol",
    response_model=EnrolAnswer,
    dependencies=[PUBLIC],
    responses={
        404: {"description": "no such enrolment token (`enrolment_unknown`)"},
        410: {
            "description": "the token was used (`enrolment_used`), replaced by a newer enrolment of the robot "
            "(`enrolment_replaced`) or has expired (`enrolment_expired`)"
        },
        429: {"description": "too many tries from this address"},
    },
)
async def enrol(body: EnrolRequest, request: Request, response: Response, services: ServicesDep) -> EnrolAnswer:
    """Uses the token (once) and answers the robot's id, broker account, broker URL (none: discover it) and
    pin. ``fleet-agent enrol`` (run by ``install-pi.sh --enrol``) writes the answer into the agent's config."""
    client = request.client.host if request.client else "?"
    wait = _per_address.take(client)
    if wait > 0:
        refused_log.warning(client, "enrolment tries from %s refused: too many", client)
        raise HTTPException(
            429, detail="too many enrolment tries; try again later", headers={"Retry-After": str(int(wait) + 1)}
        )
    try:
        got = await run_in_threadpool(redeem, services.engine, body.token, client, time.time())
    except EnrolmentRefused as exc:
        log.warning("enrolment refused for %s (%s)", client, exc.code)
        if exc.code != "enrolment_unknown":
            actor = Actor(subject="anonymous", name="enrolment", client=client)
            services.audit.record(actor, "robot_enrol_refused", None, {"reason": exc.code})
        raise ServiceError(exc.status_code, exc.detail, exc.code) from None
    key = await run_in_threadpool(fleet_key, services.settings.server_data_dir)
    log.warning("robot %s enrolled from %s: its broker password and the fleet key handed out", got.robot_id, client)
    actor = Actor(subject=f"robot:{got.robot_id}", name=got.robot_id, client=client)
    services.audit.record(actor, "robot_enrol", got.robot_id, {"broker": got.broker, "tls": got.tls_ca is not None})
    response.headers["Cache-Control"] = "no-store"
    return EnrolAnswer(
        robot_id=got.robot_id,
        username=got.robot_id,
        password=got.password,
        broker=got.broker,
        fleet_key=key.hex(),
        tls_ca=got.tls_ca,
    )
