"""Host and Origin checks with authentication OFF (the demo's setting), against a real server: a page on
another site, or one that rebinds its own name to the server's address, can neither read nor act. And the
Content-Security-Policy on every response (in the browsers: tests/frontend/test_content_security_policy.py)."""

from __future__ import annotations

import asyncio
import re
from typing import Any

import httpx
import pytest
import websockets
from websockets.exceptions import ConnectionClosed

from backend.api.routes.ui import DASHBOARD_PATHS
from backend.core.headers import CONTENT_SECURITY_POLICY
from tests.support.procs import ServerProcess

#: what a page may not carry under the policy: a script without src, a <style>, a style or on* attribute
INLINE = re.compile(r"<script(?![^>]*\ssrc=)[^>]*>|<style|\sstyle=|\son[a-z]+=", re.IGNORECASE)
COMMENT = re.compile(r"<!--.*?-->", re.DOTALL)


@pytest.fixture
def open_server(broker, database_url, workdir):
    s = ServerProcess(broker, database_url, workdir, FLEET_AUTH="off", FLEET_ALLOWED_HOSTS="fleet.lab.example")
    s.start()
    try:
        yield s
    finally:
        s.stop()


async def _ws_outcome(url: str, **kw: Any) -> tuple[str, Any]:
    async with websockets.connect(url, **kw) as ws:
        try:
            await ws.send('{"type": "subscribe", "robots": ["*"], "streams": ["*"]}')
            return "data", await asyncio.wait_for(ws.recv(), 10)
        except ConnectionClosed as exc:
            assert exc.rcvd is not None
            return "closed", (exc.rcvd.code, exc.rcvd.reason)


def test_auth_off_refuses_foreign_origins_and_hosts(open_server: ServerProcess) -> None:
    port = open_server.port
    with httpx.Client(base_url=open_server.base_url, timeout=15) as c:
        # first: the server is open (auth off), so a refusal below is the guard's, not authentication's
        own = {"Origin": f"http://127.0.0.1:{port}"}
        assert c.post("/api/estop", json={}, headers=own).status_code == 202
        assert c.post("/api/estop/release", json={}, headers=own).status_code == 202

        # a page on another site posting to the lab's server (CSRF): refused, nothing done
        evil = c.post("/api/estop", json={}, headers={"Origin": "http://evil.example"})
        assert evil.status_code == 403 and evil.json()["code"] == "cross_origin", evil.text
        assert c.get("/api/estop").json()["engaged"] is False

        # DNS rebinding: evil.example now resolves to the lab's address; its page is "same-origin"
        rebound = {"Host": f"evil.example:{port}", "Origin": f"http://evil.example:{port}"}
        for method, path in (("GET", "/api/robots"), ("POST", "/api/estop"), ("GET", "/")):
            r = c.request(method, path, json={} if method == "POST" else None, headers=rebound)
            assert r.status_code == 400 and "FLEET_ALLOWED_HOSTS" in r.json()["detail"], (method, path, r.text)
        assert c.get("/api/estop").json()["engaged"] is False

        # the names a laptop and a lab use: localhost, any address, FLEET_ALLOWED_HOSTS
        for host in (f"localhost:{port}", "localhost", f"127.0.0.1:{port}", f"[::1]:{port}", "fleet.lab.example"):
            assert c.get("/api/robots", headers={"Host": host}).status_code == 200, host
        named = {"Host": f"fleet.lab.example:{port}", "Origin": f"http://fleet.lab.example:{port}"}
        assert c.post("/api/estop/release", json={}, headers=named).status_code == 202
        assert c.post("/api/estop/release", json={}).status_code == 202  # scripts send no Origin

    # WebSocket handshakes: a foreign Origin, or a rebound Host, gets no data
    url = f"ws://127.0.0.1:{port}/ws"
    assert asyncio.run(_ws_outcome(url, origin=f"http://127.0.0.1:{port}"))[0] == "data"
    assert asyncio.run(_ws_outcome(url, origin="http://evil.example")) == ("closed", (1008, "origin not allowed"))
    rebound_url = f"ws://evil.example:{port}/ws"  # connected to 127.0.0.1, as a rebound name would be
    kind, (code, reason) = asyncio.run(
        _ws_outcome(rebound_url, origin=f"http://evil.example:{port}", host="127.0.0.1", port=port)
    )
    assert kind == "closed" and code == 1008 and "FLEET_ALLOWED_HOSTS" in reason

    _every_response_carries_the_content_security_policy(open_server)  # on the same server: one start less


def _every_response_carries_the_content_security_policy(open_server: ServerProcess) -> None:
    """Every page with the one policy (backend/core/headers.py) and nothing inline that it would refuse; the
    assets, the API's answers and the guard's refusals carry it too."""
    assert "'unsafe-" not in CONTENT_SECURITY_POLICY and "*" not in CONTENT_SECURITY_POLICY
    pages = [p.replace("{robot_id}", "r1").replace("{run_id}", "1") for p in DASHBOARD_PATHS]
    with httpx.Client(base_url=open_server.base_url, timeout=15) as c:
        for path in [*pages, "/login", "/docs"]:
            r = c.get(path)
            assert r.status_code == 200 and r.headers["content-type"].startswith("text/html"), path
            assert r.headers.get("content-security-policy") == CONTENT_SECURITY_POLICY, path
            markup = COMMENT.sub("", r.text)
            assert INLINE.search(markup) is None, (path, INLINE.search(markup))
        others = [
            c.get("/assets/js/app.js"),
            c.get("/assets/vendor/plotly.css"),
            c.get("/api/robots"),
            c.get("/api/no-such-route"),
            c.get("/", headers={"Host": "evil.example"}),
            c.post("/api/estop", json={}, headers={"Origin": "http://evil.example"}),
        ]
        assert [r.status_code for r in others] == [200, 200, 200, 404, 400, 403]
        for r in others:
            assert r.headers.get("content-security-policy") == CONTENT_SECURITY_POLICY, r.request.url
