"""Login page support: ``POST /api/auth/login`` sets an HttpOnly, SameSite=Strict session cookie;
``POST /api/auth/logout`` ends it; ``GET /api/auth/me`` says who the caller is."""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import APIRouter, Cookie, HTTPException, Request, Response
from starlette.concurrency import run_in_threadpool

from backend.api.deps import PUBLIC, VIEWER, AuthDep, ServicesDep, SocketsDep, ViewerDep
from backend.core.errors import ServiceError
from backend.core.security import SESSION_COOKIE, Principal, origin_allowed
from backend.schemas import LoginRequest, Me
from backend.services.access.audit import Actor
from backend.services.access.auth import AuthError
from fleet_common.ratelimit import RateLimitedLogger

router = APIRouter(prefix="/api/auth", tags=["auth"])
log = logging.getLogger("backend.auth")
refused_log = RateLimitedLogger(log)


def _me(principal: Principal, auth_on: bool) -> Me:
    return Me(
        name=principal.name,
        role=principal.role.label,  # type: ignore[arg-type]
        kind=principal.kind,
        username=principal.username,
        auth=auth_on,
        subject=principal.subject,
    )


def _same_origin(request: Request, auth: AuthDep) -> None:
    if not origin_allowed(request.headers.get("origin"), request.headers.get("host"), auth.allowed_origins):
        raise HTTPException(403, detail="cross-origin request refused")


@router.post(
    "/login",
    response_model=Me,
    dependencies=[PUBLIC],
    responses={
        401: {"description": "wrong username or password"},
        429: {"description": "too many attempts (from this address, for this name, or from everyone)"},
        503: {"description": "too many password checks running or waiting"},
    },
)
async def login(body: LoginRequest, request: Request, response: Response, auth: AuthDep, services: ServicesDep) -> Me:
    """Checks the password and sets the session cookie (``fleet_session``, HttpOnly, SameSite=Strict).
    Every checked attempt, failed or not, is logged and audited (``login``, ``login_failed``)."""
    _same_origin(request, auth)
    client = request.client.host if request.client else "?"
    wait = auth.logins.wait(body.username, client)
    if wait > 0:  # refused before any password is checked; logged at most once per address and 5 s
        refused_log.warning(client, "login attempts from %s refused: too many (last for %r)", client, body.username)
        raise HTTPException(
            429,
            detail="too many login attempts; try again later",
            headers={"Retry-After": auth.logins.retry_after_header(wait)},
        )
    try:
        principal, secret = await auth.login(body.username, body.password)
    except AuthError as exc:
        log.warning("failed login for %r from %s (%s)", body.username, client, exc.code)
        failed = Actor(subject="anonymous", name=body.username, client=client)
        services.audit.record(failed, "login_failed", None, {"username": body.username, "reason": exc.code})
        raise ServiceError(exc.status_code, exc.detail, exc.code, headers={"WWW-Authenticate": "Bearer"}) from None
    actor = Actor(subject=principal.subject, name=principal.name, token_id=principal.token_id, client=client)
    services.audit.record(actor, "login", None, {"username": body.username})
    response.set_cookie(
        SESSION_COOKIE,
        secret,
        max_age=int(auth.session_ttl_s),
        path="/",
        httponly=True,
        samesite="strict",
        secure=auth.settings.cookie_secure or request.url.scheme == "https",
    )
    return _me(principal, auth.enabled)


@router.post("/logout", status_code=204, dependencies=[PUBLIC])
async def logout(
    request: Request,
    auth: AuthDep,
    services: ServicesDep,
    sockets: SocketsDep,
    session: Annotated[str | None, Cookie(alias=SESSION_COOKIE, include_in_schema=False)] = None,
) -> Response:
    """Ends the caller's own browser session (if any) and clears the cookie; its WebSockets close (1008)."""
    _same_origin(request, auth)
    if session:
        principal = await run_in_threadpool(auth.principal_for_session, session)
        if principal is not None:  # its sockets first (not one set-point more), then the leases it held
            if principal.token_id is not None:
                sockets.session_ended(principal.token_id)
            actor = Actor(subject=principal.subject, name=principal.name, token_id=principal.token_id)
            await services.leases.release_all_of(actor)
        await run_in_threadpool(auth.logout, session)
    response = Response(status_code=204)
    response.delete_cookie(SESSION_COOKIE, path="/", httponly=True, samesite="strict")
    return response


@router.get("/me", response_model=Me, dependencies=[VIEWER])
async def me(principal: ViewerDep, auth: AuthDep) -> Me:
    return _me(principal, auth.enabled)
