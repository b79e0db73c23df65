"""Users who log in to the dashboard (admin): create, list, change role/password, disable, delete."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, TypeVar

from fastapi import APIRouter, HTTPException, Path, Response
from starlette.concurrency import run_in_threadpool

from backend.api.deps import ADMIN, AuthDep
from backend.core.security import USERNAME_PATTERN
from backend.services.auth import AuthError, UserCreate, UserPublic, UserUpdate

router = APIRouter(prefix="/api/users", tags=["auth"], dependencies=[ADMIN])

Username = Annotated[str, Path(pattern=USERNAME_PATTERN)]
T = TypeVar("T")


async def _run(fn: Callable[..., T], *args: object) -> T:
    try:
        return await run_in_threadpool(fn, *args)
    except AuthError as exc:
        raise HTTPException(exc.status_code, detail=exc.detail) from None


@router.get("", response_model=list[UserPublic])
async def list_users(auth: AuthDep) -> list[UserPublic]:
    return await _run(auth.list_users)


@router.post("", response_model=UserPublic, status_code=201, responses={409: {"description": "user exists"}})
async def create_user(body: UserCreate, auth: AuthDep) -> UserPublic:
    return await _run(auth.create_user, body)


@router.get("/{username}", response_model=UserPublic, responses={404: {"description": "unknown user"}})
async def get_user(username: Username, auth: AuthDep) -> UserPublic:
    return await _run(auth.get_user, username)


@router.patch("/{username}", response_model=UserPublic, responses={404: {"description": "unknown user"}})
async def update_user(username: Username, body: UserUpdate, auth: AuthDep) -> UserPublic:
    """A new password or disabling the user ends their browser sessions; a role change applies at once."""
    return await _run(auth.update_user, username, body)


@router.delete("/{username}", status_code=204, responses={404: {"description": "unknown user"}})
async def delete_user(username: Username, auth: AuthDep) -> Response:
    await _run(auth.delete_user, username)
    return Response(status_code=204)
