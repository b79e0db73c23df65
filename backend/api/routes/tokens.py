"""API tokens for scripts (admin): create (the secret is shown once), list, revoke."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Path, Response
from starlette.concurrency import run_in_threadpool

from backend.api.deps import ADMIN, AdminDep, AuthDep
from backend.services.auth import AuthError, TokenCreate, TokenCreated, TokenPublic

router = APIRouter(prefix="/api/tokens", tags=["auth"], dependencies=[ADMIN])


@router.get("", response_model=list[TokenPublic])
async def list_tokens(auth: AuthDep) -> list[TokenPublic]:
    """Every API token (never the secrets: only their hashes are stored)."""
    return await run_in_threadpool(auth.list_tokens)


@router.post("", response_model=TokenCreated, status_code=201)
async def create_token(body: TokenCreate, auth: AuthDep, principal: AdminDep) -> TokenCreated:
    """A new token with the given role. ``token`` is in this response only: store it now."""
    return await run_in_threadpool(auth.create_token, body, principal.name)


@router.delete("/{token_id}", status_code=204, responses={404: {"description": "unknown token"}})
async def revoke_token(auth: AuthDep, token_id: str = Path(max_length=32)) -> Response:
    """Revoked at once on this server (other replicas within 5 s)."""
    try:
        await run_in_threadpool(auth.revoke_token, token_id)
    except AuthError as exc:
        raise HTTPException(exc.status_code, detail=exc.detail) from None
    return Response(status_code=204)
