"""Login page support: ``POST /api/auth/login`` sets an HttpOnly, SameSite=Strict session cookie;
``POST /api/auth/logout`` ends it; ``GET /api/auth/me`` says who the caller is."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Cookie, HTTPException, Request, Response
from starlette.concurrency import run_in_threadpool

from backend.api.deps import PUBLIC, VIEWER, AuthDep, ServicesDep, ViewerDep
from backend.core.errors import ServiceError
from backend.core.security import SESSION_COOKIE, Principal, origin_allowed
from backend.schemas import LoginRequest, Me
from backend.services.access.audit import Actor
from backend.services.access.auth import AuthError

router = APIRouter(prefix="/api/auth", tags=["auth"])


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
    responses={401: {"description": "wrong username or password"}, 429: {"description": "too many attempts"}},
)
async def login(body: LoginRequest, request: Request, response: Response, auth: AuthDep) -> Me:
    """Checks the password and sets the session cookie (``fleet_session``, HttpOnly, SameSite=Strict)."""
    _same_origin(request, auth)
    client = request.client.host if request.client else "?"
    wait = auth.logins.take((body.username.lower(), client))
    if wait > 0:
        raise HTTPException(
            429,
            detail="too many login attempts; try again later",
            headers={"Retry-After": auth.logins.retry_after_header(wait)},
        )
    try:
        principal, secret = await auth.login(body.username, body.password)
    except AuthError as exc:
        raise ServiceError(exc.status_code, exc.detail, exc.code, headers={"WWW-Authenticate": "Bearer"}) from None
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
    session: Annotated[str | None, Cookie(alias=SESSION_COOKIE, include_in_schema=False)] = None,
) -> Response:
    """Ends the caller's own browser session (if any) and clears the cookie."""
    _same_origin(request, auth)
    if session:
        principal = await run_in_threadpool(auth.principal_for_session, session)
        if principal is not None:  # the leases this user held go with the session
            actor = Actor(subject=principal.subject, name=principal.name, token_id=principal.token_id)
            await services.leases.release_all_of(actor)
        await run_in_threadpool(auth.logout, session)
    response = Response(status_code=204)
    response.delete_cookie(SESSION_COOKIE, path="/", httponly=True, samesite="strict")
    return response


@router.get("/me", response_model=Me, dependencies=[VIEWER])
async def me(principal: ViewerDep, auth: AuthDep) -> Me:
    return _me(principal, auth.enabled)
