"""API tokens for scripts (admin): create (the secret is shown once), list, revoke. Creating and revoking
go to the audit trail (``token_create``, ``token_revoke``; never the secret)."""

from __future__ import annotations

import logging

from fastapi import APIRouter, Path, Response
from starlette.concurrency import run_in_threadpool

from backend.api.deps import ADMIN, ActorDep, AdminDep, AuthDep, ServicesDep, SocketsDep
from backend.schemas import TokenCreate, TokenCreated, TokenPublic
from backend.services.access.auth import AuthError

audit = logging.getLogger("backend.audit")
router = APIRouter(prefix="/api/tokens", tags=["auth"], dependencies=[ADMIN])


@router.get("", response_model=list[TokenPublic])
async def list_tokens(auth: AuthDep) -> list[TokenPublic]:
    """Every API token (never the secrets: only their hashes are stored)."""
    return await run_in_threadpool(auth.tokens.list_all)


@router.post(
    "",
    response_model=TokenCreated,
    status_code=201,
    responses={422: {"description": "a bad field, or expires_in_s beyond FLEET_TOKEN_TTL_DAYS"}},
)
async def create_token(
    body: TokenCreate, auth: AuthDep, principal: AdminDep, services: ServicesDep, actor: ActorDep
) -> TokenCreated:
    """A new token with the given role (``metrics``: ``GET /metrics`` only, for Prometheus). It expires after
    ``expires_in_s``, at most and by default FLEET_TOKEN_TTL_DAYS, and answers to the user who makes it (or
    whom the caller's token answers to): disabled, deleted or demoted below its role, it stops working.
    ``token`` is in this response only: store it now."""
    created = await run_in_threadpool(auth.tokens.create, body, principal.name, principal.owner)
    services.audit.record(
        actor,
        "token_create",
        None,
        {"token": created.id, "name": created.name, "role": created.role, "expires_at": created.expires_at},
    )
    return created


@router.delete("/{token_id}", status_code=204, responses={404: {"description": "unknown token"}})
async def revoke_token(
    auth: AuthDep,
    principal: AdminDep,
    services: ServicesDep,
    actor: ActorDep,
    sockets: SocketsDep,
    token_id: str = Path(max_length=32),
) -> Response:
    """Revoked at once on this server (other replicas within 5 s); its open WebSockets are closed (1008) before
    this answers (on other replicas within about a second)."""
    try:
        await run_in_threadpool(auth.revoke_token, token_id)
    except AuthError as exc:
        raise exc from None  # a ServiceError: the app's handler answers it
    sockets.token_revoked(token_id)
    audit.info("API token %s revoked by %s", token_id, principal.name)
    services.audit.record(actor, "token_revoke", None, {"token": token_id})
    return Response(status_code=204)
