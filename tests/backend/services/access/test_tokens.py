"""API tokens expire and answer to the user who made them (issue 29 #9), against a real server: by default they
live FLEET_TOKEN_TTL_DAYS and cannot ask for longer; one made by a user stops working, and its WebSocket
closes, when that user is demoted below it, disabled or deleted; a token from before tokens expired gets an
expiry at the server's start."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import httpx
import orjson
import websockets
from sqlalchemy import create_engine, insert
from websockets.exceptions import ConnectionClosed

from backend.core.security import hash_token
from backend.models import ApiToken
from tests.support.procs import ServerProcess

DAY_S = 86400.0
OLD_SECRET = "flt_made-before-tokens-expired-0123456789abcdef"
PASSWORD = "tara-password-1"


def _old_token(database_url: str) -> None:
    """A token as the server made them before: no expiry, no user."""
    engine = create_engine(database_url)
    try:
        with engine.begin() as conn:
            conn.execute(
                insert(ApiToken).values(
                    id="tok_oldoldold01",
                    kind="api",
                    name="old-script",
                    role="operator",
                    user_id=None,
                    token_hash=hash_token(OLD_SECRET),
                    created_at=time.time() - 400 * DAY_S,
                    created_by="FLEET_ADMIN_TOKEN",
                    expires_at=None,
                )
            )
    finally:
        engine.dispose()


def _works(server: ServerProcess, token: str) -> int:
    with server.client(token) as c:
        return c.get("/api/robots").status_code


async def _closed_when(server: ServerProcess, token: str, change: Any) -> tuple[int, str]:
    """Open /ws with ``token``, see data, run ``change`` (blocking) and return how the server closed it."""
    headers = {"Authorization": f"Bearer {token}"}
    async with websockets.connect(f"ws://127.0.0.1:{server.port}/ws", additional_headers=headers) as ws:
        await ws.send(orjson.dumps({"type": "subscribe", "robots": ["*"], "streams": ["*"]}).decode())
        await asyncio.wait_for(ws.recv(), 10)
        await asyncio.to_thread(change)
        try:
            while True:
                await asyncio.wait_for(ws.recv(), 10)
        except ConnectionClosed as exc:
            assert exc.rcvd is not None
            return exc.rcvd.code, exc.rcvd.reason


def test_tokens_expire_and_answer_to_the_user_who_made_them(broker, database_url: str, workdir: Path) -> None:
    _old_token(database_url)
    server = ServerProcess(broker, database_url, workdir)
    started = time.time()
    server.start()
    try:
        with server.client() as admin:
            assert admin.post("/api/users", json={"username": "tara", "password": PASSWORD, "role": "admin"}).is_success
            old = next(t for t in admin.get("/api/tokens").json() if t["name"] == "old-script")
            # made before tokens expired: it still works, for FLEET_TOKEN_TTL_DAYS from the upgrade
            assert started < old["expires_at"] - 90 * DAY_S < time.time() and old["owner"] is None, old
            assert _works(server, OLD_SECRET) == 200

        # tara (an admin, logged in) makes tokens: they expire in 90 days at most, and answer to her
        with httpx.Client(base_url=server.base_url, timeout=15, headers={"Origin": server.base_url}) as tara:
            assert tara.post("/api/auth/login", json={"username": "tara", "password": PASSWORD}).status_code == 200
            made = {
                role: tara.post("/api/tokens", json={"name": f"tara-{role}", "role": role}).json()
                for role in ("operator", "admin")
            }
            too_long = tara.post("/api/tokens", json={"name": "forever", "role": "viewer", "expires_in_s": 91 * DAY_S})
            assert too_long.status_code == 422 and too_long.json()["code"] == "token_lifetime_too_long", too_long.text
            assert "FLEET_TOKEN_TTL_DAYS" in too_long.json()["detail"]
            short = tara.post("/api/tokens", json={"name": "short", "role": "viewer", "expires_in_s": 3600}).json()
        for t in made.values():
            assert t["owner"] == "tara" and abs(t["expires_at"] - t["created_at"] - 90 * DAY_S) < 1, t
        assert abs(short["expires_at"] - short["created_at"] - 3600) < 1
        op, adm = made["operator"]["token"], made["admin"]["token"]
        assert (_works(server, op), _works(server, adm)) == (200, 200)

        with server.client() as admin:
            # demoted to operator: her admin token stops, her operator token goes on
            assert admin.patch("/api/users/tara", json={"role": "operator"}).status_code == 200
            assert (_works(server, op), _works(server, adm)) == (200, 401)
            # disabled: her operator token stops too, and its open socket is closed
            closed = asyncio.run(
                _closed_when(server, op, lambda: admin.patch("/api/users/tara", json={"disabled": True}))
            )
            assert closed == (1008, "user disabled (the token's user)"), closed
            assert _works(server, op) == 401
            # enabled again, it answers again; deleted, it is revoked (a new user may get her id)
            assert admin.patch("/api/users/tara", json={"disabled": False}).status_code == 200
            assert _works(server, op) == 200
            assert admin.delete("/api/users/tara").status_code == 204
            assert _works(server, op) == 401
            listed = {t["name"]: t for t in admin.get("/api/tokens").json()}
            assert listed["tara-operator"]["revoked"] is True and listed["tara-admin"]["revoked"] is True
            assert listed["short"]["revoked"] is True and listed["old-script"]["revoked"] is False
        assert _works(server, OLD_SECRET) == 200  # answers to nobody: none of this touched it
    finally:
        server.stop()
