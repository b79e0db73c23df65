"""Annotated dependencies: services, settings, robots, and who may call what.

Authorization is deny by default: ``create_app`` refuses to build an app with a route that declares no
role (``check_route_roles``), and every route declares one of ``PUBLIC``, ``METRICS`` (``GET /metrics`` only:
a metrics token may call nothing else), ``VIEWER``, ``OPERATOR``, ``ADMIN`` (HTTP) or ``WS_VIEWER``,
``WS_OPERATOR`` (WebSocket), usually once per router. A route may add a stricter role; the strictest one
applies. See docs/security.md.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager
from typing import Annotated, Any

from fastapi import Depends, FastAPI, HTTPException, Request, WebSocket
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute, APIWebSocketRoute
from fastapi.security import APIKeyCookie, HTTPAuthorizationCredentials, HTTPBearer
from starlette.concurrency import run_in_threadpool
from starlette.websockets import WebSocketState

from backend.core.config import Settings
from backend.core.errors import ServiceError
from backend.core.security import AUTH_OFF_PRINCIPAL, SESSION_COOKIE, Principal, Role, origin_allowed
from backend.services.access.audit import Actor
from backend.services.access.auth import AuthService
from backend.services.access.sockets import HeldSocket, SocketHolders
from backend.services.fleet.registry import RobotState
from backend.services.lifecycle import Services

# The dependencies below are ``async def`` although they never await: FastAPI runs every plain ``def``
# dependency in its thread pool, and that hop (twice per command) cost about a millisecond of each
# request under load, waiting for the GIL behind the MQTT thread.


async def get_services(request: Request) -> Services:
    services: Services = request.app.state.services
    return services


async def get_ws_services(websocket: WebSocket) -> Services:
    services: Services = websocket.app.state.services
    return services


async def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


ServicesDep = Annotated[Services, Depends(get_services)]
WsServicesDep = Annotated[Services, Depends(get_ws_services)]
SettingsDep = Annotated[Settings, Depends(get_settings)]


async def get_robot(robot_id: str, services: ServicesDep) -> RobotState:
    st = services.registry.get(robot_id)
    if st is None:
        raise ServiceError(404, f"unknown robot {robot_id!r}", "unknown_robot")
    return st


RobotDep = Annotated[RobotState, Depends(get_robot)]


# ---------------------------------------------------------------------------------------------------
# Authentication and roles
# ---------------------------------------------------------------------------------------------------

#: Attribute on a dependency callable naming the role it enforces (``None``: deliberately public).
ROLE_ATTR = "__fleet_role__"
PUBLIC_MARK = "public"
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})

bearer_scheme = HTTPBearer(
    auto_error=False,
    description="An API token (`POST /api/tokens`, `fleet-server create-admin`) or FLEET_ADMIN_TOKEN.",
)
cookie_scheme = APIKeyCookie(
    name=SESSION_COOKIE, auto_error=False, description="The browser session set by `POST /api/auth/login`."
)


def auth_service(request: Request) -> AuthService:
    auth: AuthService = request.app.state.auth
    return auth


async def get_auth(request: Request) -> AuthService:
    return auth_service(request)


AuthDep = Annotated[AuthService, Depends(get_auth)]


def _unauthorized(detail: str = "authentication required") -> HTTPException:
    return HTTPException(401, detail=detail, headers={"WWW-Authenticate": "Bearer"})


async def _lookup(find: Callable[..., Principal | None], credential: str) -> Principal | None:
    """From memory on the event loop when it can (the admin token, a recently seen token or session):
    the thread hop for the database costs about a millisecond of every request under load."""
    principal = find(credential, memory_only=True)
    if principal is not None:
        return principal
    return await run_in_threadpool(find, credential)


async def _identify(
    request: Request, bearer: HTTPAuthorizationCredentials | None, cookie: str | None
) -> Principal | None:
    """The caller, or None; raises 401 for a presented but invalid credential, 403 for a cross-origin
    write with the session cookie."""
    auth = auth_service(request)
    if not auth.enabled:
        return AUTH_OFF_PRINCIPAL
    if bearer is not None:
        principal = await _lookup(auth.principal_for_token, bearer.credentials)
        if principal is None:
            raise _unauthorized("invalid, expired or revoked token")
        return principal
    if cookie:
        principal = await _lookup(auth.principal_for_session, cookie)
        if principal is None:
            raise _unauthorized("session expired; log in again")
        if request.method not in SAFE_METHODS and not origin_allowed(
            request.headers.get("origin"), request.headers.get("host"), auth.allowed_origins
        ):
            raise HTTPException(403, detail="cross-origin request refused")
        return principal
    return None


async def authenticate(
    request: Request,
    bearer: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)],
    cookie: Annotated[str | None, Depends(cookie_scheme)],
) -> Principal:
    principal = await _identify(request, bearer, cookie)
    if principal is None:
        raise _unauthorized()
    request.state.principal = principal
    return principal


async def optional_principal(
    request: Request,
    bearer: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)],
    cookie: Annotated[str | None, Depends(cookie_scheme)],
) -> Principal | None:
    """For public routes that show more to callers who authenticate (``/api/health``)."""
    try:
        return await _identify(request, bearer, cookie)
    except HTTPException:
        return None


def _role_dependency(role: Role) -> Callable[..., Any]:
    async def check(principal: Annotated[Principal, Depends(authenticate)]) -> Principal:
        if not principal.allows(role):
            raise HTTPException(403, detail=f"{role.label} role required (you are {principal.role.label})")
        return principal

    check.__name__ = check.__qualname__ = f"require_{role.label}"
    setattr(check, ROLE_ATTR, role)
    return check


async def public() -> None:
    """Marks a route as deliberately public (no credentials needed)."""


setattr(public, ROLE_ATTR, PUBLIC_MARK)

require_metrics = _role_dependency(Role.METRICS)
require_viewer = _role_dependency(Role.VIEWER)
require_operator = _role_dependency(Role.OPERATOR)
require_admin = _role_dependency(Role.ADMIN)

#: For ``dependencies=[...]`` of a router or route.
PUBLIC = Depends(public)
#: ``GET /metrics`` alone: every role passes, and a ``metrics`` token passes nowhere else
METRICS = Depends(require_metrics)
VIEWER = Depends(require_viewer)
OPERATOR = Depends(require_operator)
ADMIN = Depends(require_admin)


async def get_actor(request: Request, principal: Annotated[Principal, Depends(authenticate)]) -> Actor:
    """Who acts, for the audit trail and the control lease. With authentication off every caller is the
    same principal, so the lease holder is the client's own id (``X-Fleet-Client``: a browser tab, a
    script), and two tabs do not drive one robot at once."""
    client = request.client.host if request.client else ""
    holder = ""
    if principal is AUTH_OFF_PRINCIPAL:
        tab = (request.headers.get("x-fleet-client") or "").strip()[:64]
        holder = f"client:{tab}" if tab else ""
    return Actor(
        subject=principal.subject,
        name=principal.name if not holder else f"{principal.name} {holder}",
        token_id=principal.token_id,
        client=client,
        holder=holder,
    )


ActorDep = Annotated[Actor, Depends(get_actor)]

#: For an endpoint that also needs to know who calls.
ViewerDep = Annotated[Principal, Depends(require_viewer)]
OperatorDep = Annotated[Principal, Depends(require_operator)]
AdminDep = Annotated[Principal, Depends(require_admin)]
OptionalPrincipalDep = Annotated[Principal | None, Depends(optional_principal)]


# --- WebSocket ---------------------------------------------------------------------------------------


class WebSocketDenied(Exception):
    """Raised by a WebSocket role dependency; the app's handler accepts and closes with 1008 at once,
    before the endpoint runs, so the client gets a close code and reason but never any data."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


async def websocket_denied_handler(websocket: WebSocket, exc: Exception) -> None:
    reason = exc.reason if isinstance(exc, WebSocketDenied) else "policy violation"
    if websocket.client_state == WebSocketState.CONNECTING:
        await websocket.accept()
    await websocket.close(code=1008, reason=reason[:120])


def _ws_role_dependency(role: Role) -> Callable[..., Any]:
    async def check(websocket: WebSocket) -> Principal:
        auth: AuthService = websocket.app.state.auth
        if not origin_allowed(websocket.headers.get("origin"), websocket.headers.get("host"), auth.allowed_origins):
            raise WebSocketDenied("origin not allowed")
        if not auth.enabled:
            return AUTH_OFF_PRINCIPAL
        principal: Principal | None = None
        header = websocket.headers.get("authorization", "")
        scheme, _, credentials = header.partition(" ")
        token = credentials.strip() if scheme.lower() == "bearer" else websocket.query_params.get("token")
        if token:
            principal = await _lookup(auth.principal_for_token, token)
        elif cookie := websocket.cookies.get(SESSION_COOKIE):
            principal = await _lookup(auth.principal_for_session, cookie)
        if principal is None:
            raise WebSocketDenied("authentication required")
        if not principal.allows(role):
            raise WebSocketDenied(f"{role.label} role required")
        websocket.state.principal = principal
        return principal

    check.__name__ = check.__qualname__ = f"require_ws_{role.label}"
    setattr(check, ROLE_ATTR, role)
    return check


require_ws_viewer = _ws_role_dependency(Role.VIEWER)
WS_VIEWER = Depends(require_ws_viewer)
require_ws_operator = _ws_role_dependency(Role.OPERATOR)
#: A WebSocket that drives a robot (``/ws/control/{robot_id}``).
WS_OPERATOR = Depends(require_ws_operator)


def socket_holders(request: Request) -> SocketHolders:
    holders: SocketHolders = request.app.state.sockets
    return holders


async def get_socket_holders(request: Request) -> SocketHolders:
    return socket_holders(request)


#: For the access routes, which deny the sockets of a principal they revoke, disable, demote or log out.
SocketsDep = Annotated[SocketHolders, Depends(get_socket_holders)]


def held_socket(websocket: WebSocket, needs: Role) -> AbstractContextManager[HeldSocket]:
    """An accepted socket, held for as long as it is open: when its principal is revoked, disabled, demoted
    below ``needs`` or logged out, ``held.denied`` says why and the route closes it (1008)."""
    holders: SocketHolders = websocket.app.state.sockets
    principal: Principal = getattr(websocket.state, "principal", AUTH_OFF_PRINCIPAL)
    return holders.hold(principal, needs)


async def close_held(websocket: WebSocket, held: HeldSocket, code: int) -> None:
    """Close a socket still open: 1008 and the reason when its principal may no longer hold it."""
    if websocket.client_state == WebSocketState.CONNECTED:
        with contextlib.suppress(Exception):
            if held.denied is not None:
                await websocket.close(code=1008, reason=held.denied)
            else:
                await websocket.close(code=code)


# --- deny by default -----------------------------------------------------------------------------------


def _declared(dependant: Dependant) -> Iterator[Role | str]:
    for dep in dependant.dependencies:
        mark = getattr(dep.call, ROLE_ATTR, None)
        if mark is not None:
            yield mark
        yield from _declared(dep)


def iter_api_routes(app: FastAPI) -> Iterator[tuple[str, list[str], Dependant]]:
    """(path, methods or ["WS"], dependant) of every FastAPI route, router prefixes and router-level
    dependencies applied (FastAPI >= 0.16x keeps included routers lazily: ``iter_route_contexts``)."""
    try:
        from fastapi.routing import iter_route_contexts  # type: ignore[attr-defined, unused-ignore]

        items: Iterable[Any] = iter_route_contexts(app.routes)
    except ImportError:  # older FastAPI: app.routes is already flat
        items = app.routes
    for item in items:
        original = getattr(item, "original_route", item)
        if not isinstance(original, APIRoute | APIWebSocketRoute):
            continue
        dependant = item.dependant
        methods = sorted(item.methods or []) if isinstance(original, APIRoute) else ["WS"]
        yield item.path, methods, dependant


def route_role(dependant: Dependant) -> Role | str | None:
    """The strictest role a route declares, ``"public"``, or None when it declares nothing."""
    marks = list(_declared(dependant))
    roles = [m for m in marks if isinstance(m, Role)]
    if roles:
        return max(roles)
    return PUBLIC_MARK if marks else None


def route_roles(app: FastAPI) -> dict[tuple[str, str], Role | str | None]:
    """{(method, path): declared role} for every route (``"WS"`` as the method of WebSocket routes)."""
    return {(m, path): route_role(dep) for path, methods, dep in iter_api_routes(app) for m in methods}


def check_route_roles(app: FastAPI) -> None:
    """Refuse to build an app with an undeclared route: a new route without a role fails at start."""
    missing = [f"{m} {path}" for (m, path), role in route_roles(app).items() if role is None]
    if missing:
        raise RuntimeError(f"routes without a role declaration (see backend/api/deps.py): {missing}")
