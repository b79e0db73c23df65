"""Users who log in to the dashboard (admin): create, list, change role/password, disable, delete.

Every change goes to the audit trail (``GET /api/audit``: ``user_create``, ``user_update``, ``user_delete``)
with the admin who made it, as e-stops and tokens do, and to the ``backend.audit`` log. An admin
cannot disable, demote or delete their own account here: another admin (or the CLI) must, so a slip of
the mouse cannot lock the last admin out."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Annotated, TypeVar

from fastapi import APIRouter, Path, Response
from starlette.concurrency import run_in_threadpool

from backend.api.deps import ADMIN, ActorDep, AdminDep, AuthDep, ServicesDep, SocketsDep
from backend.core.errors import ServiceError
from backend.core.security import USERNAME_PATTERN, Principal, Role
from backend.schemas import UserCreate, UserPublic, UserUpdate
from backend.services.access.auth import AuthError

audit = logging.getLogger("backend.audit")
router = APIRouter(prefix="/api/users", tags=["auth"], dependencies=[ADMIN])

Username = Annotated[str, Path(pattern=USERNAME_PATTERN)]
T = TypeVar("T")


async def _run(fn: Callable[..., T], *args: object) -> T:
    try:
        return await run_in_threadpool(fn, *args)
    except AuthError as exc:
        raise exc from None  # a ServiceError: the app's handler answers it


@router.get("", response_model=list[UserPublic])
async def list_users(auth: AuthDep) -> list[UserPublic]:
    return await _run(auth.list_users)


def _refuse_self(principal: Principal, username: str, what: str) -> None:
    if principal.owner is not None and principal.owner == username:  # their session, or a token they made
        raise ServiceError(409, f"you cannot {what} your own account; another admin can", "own_account")


@router.post("", response_model=UserPublic, status_code=201, responses={409: {"description": "user exists"}})
async def create_user(
    body: UserCreate, auth: AuthDep, principal: AdminDep, services: ServicesDep, actor: ActorDep
) -> UserPublic:
    user = await _run(auth.create_user, body, await auth.hash_password(body.password))
    audit.info("user %s (%s) created by %s", user.username, user.role, principal.name)
    services.audit.record(actor, "user_create", None, {"user": user.username, "role": user.role})
    return user


@router.get("/{username}", response_model=UserPublic, responses={404: {"description": "unknown user"}})
async def get_user(username: Username, auth: AuthDep) -> UserPublic:
    return await _run(auth.get_user, username)


@router.patch(
    "/{username}",
    response_model=UserPublic,
    responses={404: {"description": "unknown user"}, 409: {"description": "your own account"}},
)
async def update_user(
    username: Username,
    body: UserUpdate,
    auth: AuthDep,
    principal: AdminDep,
    services: ServicesDep,
    actor: ActorDep,
    sockets: SocketsDep,
) -> UserPublic:
    """A new password or disabling the user ends their browser sessions; a role change applies at once. The API
    tokens they made stop working while they are disabled or hold a role below the token's.
    Their WebSockets go with them (1008): all of them when their sessions end, those needing more than a new
    role, and those of the tokens that stopped."""
    if body.disabled:
        _refuse_self(principal, username, "disable")
    if body.role is not None and body.role != "admin":
        _refuse_self(principal, username, "demote")
    digest = await auth.hash_password(body.password) if body.password is not None else None
    user = await _run(auth.update_user, username, body, digest)
    gone = "user disabled" if body.disabled else ("password changed" if body.password is not None else None)
    role = Role.parse(body.role) if body.role is not None else None
    sockets.user_changed(username, role=role, gone=gone, tokens_too=bool(body.disabled))
    changes = [
        f"role {body.role}" if body.role is not None else "",
        "new password" if body.password is not None else "",
        ("disabled" if body.disabled else "enabled") if body.disabled is not None else "",
    ]
    audit.info("user %s changed (%s) by %s", username, ", ".join(c for c in changes if c) or "nothing", principal.name)
    detail: dict[str, object] = {"user": username}
    if body.role is not None:
        detail["role"] = body.role
    if body.password is not None:
        detail["password_reset"] = True  # never the password itself
    if body.disabled is not None:
        detail["disabled"] = body.disabled
    services.audit.record(actor, "user_update", None, detail)
    return user


@router.delete(
    "/{username}",
    status_code=204,
    responses={404: {"description": "unknown user"}, 409: {"description": "your own account"}},
)
async def delete_user(
    username: Username, auth: AuthDep, principal: AdminDep, services: ServicesDep, actor: ActorDep, sockets: SocketsDep
) -> Response:
    _refuse_self(principal, username, "delete")
    await _run(auth.delete_user, username)
    sockets.user_changed(username, gone="user deleted", tokens_too=True)
    audit.info("user %s deleted by %s", username, principal.name)
    services.audit.record(actor, "user_delete", None, {"user": username})
    return Response(status_code=204)
