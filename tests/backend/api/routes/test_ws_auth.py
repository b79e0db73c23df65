"""WebSocket authentication: checked before any data, refused with close code 1008; Origin checked."""

from __future__ import annotations

import asyncio
from typing import Any

import orjson
import pytest
import websockets
from websockets.exceptions import ConnectionClosed

from tests.backend.api.conftest import new_token
from tests.support.procs import wait_for

SUBSCRIBE = orjson.dumps({"type": "subscribe", "robots": ["*"], "streams": ["*"]}).decode()


async def _outcome(url: str, **kw: Any) -> tuple[str, Any]:
    """("data", first frame) or ("closed", (code, reason)) with nothing received before the close."""
    async with websockets.connect(url, **kw) as ws:
        try:
            await ws.send(SUBSCRIBE)
            return "data", await asyncio.wait_for(ws.recv(), 10)
        except ConnectionClosed as exc:
            assert exc.rcvd is not None
            return "closed", (exc.rcvd.code, exc.rcvd.reason)


def _run(url: str, **kw: Any) -> tuple[str, Any]:
    return asyncio.run(_outcome(url, **kw))


def _bare(server, path: str = "/ws") -> str:
    return f"ws://127.0.0.1:{server.port}{path}"


@pytest.mark.parametrize("path", ["/ws", "/ws/camera/r1"])
def test_websocket_refused_without_valid_credentials(server, path):
    for url, kw in [
        (_bare(server, path), {}),
        (_bare(server, path) + "?token=flt_wrong", {}),
        (_bare(server, path), {"additional_headers": {"Authorization": "Bearer flt_wrong"}}),
        (_bare(server, path), {"additional_headers": {"Cookie": "fleet_session=fls_forged"}}),
    ]:
        kind, detail = _run(url, **kw)
        assert kind == "closed" and detail[0] == 1008, (url, kw, detail)


def test_websocket_with_token_header_cookie(server, role_client):
    kind, frame = _run(server.ws_url)  # admin ?token=
    assert kind == "data" and orjson.loads(frame)[0]["type"] == "snapshot"
    viewer = new_token(server, "viewer")
    kind, frame = _run(_bare(server), additional_headers={"Authorization": f"Bearer {viewer}"})
    assert kind == "data"
    with server.client() as admin:
        admin.post("/api/users", json={"username": "wsuser", "password": "ws-password", "role": "viewer"})
    with server.client(anonymous=True) as c:
        session = c.post("/api/auth/login", json={"username": "wsuser", "password": "ws-password"}).cookies[
            "fleet_session"
        ]
    kind, frame = _run(_bare(server), additional_headers={"Cookie": f"fleet_session={session}"}, origin=server.base_url)
    assert kind == "data"


def test_websocket_origin_checked(server):
    kind, detail = _run(server.ws_url, origin="http://evil.example")
    assert kind == "closed" and detail == (1008, "origin not allowed")
    kind, detail = _run(server.ws_camera_url("r1"), origin="http://localhost.evil.example")
    assert kind == "closed" and detail[0] == 1008
    assert _run(server.ws_url, origin=f"http://127.0.0.1:{server.port}")[0] == "data"


def test_allowed_origins_setting(broker, database_url, workdir):
    from tests.support.procs import ServerProcess

    s = ServerProcess(broker, database_url, workdir, FLEET_ALLOWED_ORIGINS="https://fleet.lab.example")
    s.start()
    try:
        assert _run(s.ws_url, origin="https://fleet.lab.example")[0] == "data"
        assert _run(s.ws_url, origin="https://other.example")[1][0] == 1008
    finally:
        s.stop()


def test_revoked_token_refused_on_websocket(server):
    with server.client() as admin:
        created = admin.post("/api/tokens", json={"name": "ws", "role": "viewer"}).json()
        assert _run(f"{_bare(server)}?token={created['token']}")[0] == "data"
        assert admin.delete(f"/api/tokens/{created['id']}").status_code == 204
    assert _run(f"{_bare(server)}?token={created['token']}")[1][0] == 1008


def test_token_never_in_logs(server):
    _run(server.ws_url)
    # the server writes its access line after the client has its answer: wait for it, then look for the token
    wait_for(lambda: "token=***" in server.output(), 10, what="the redacted WebSocket access line")
    assert server.token is not None and server.token not in server.output()
