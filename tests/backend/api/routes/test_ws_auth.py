"""WebSocket authentication: checked before any data, refused with close code 1008; Origin checked."""

from __future__ import annotations

import asyncio
import contextlib
import math
import statistics
import time
from typing import Any

import orjson
import pytest
import websockets
from websockets.exceptions import ConnectionClosed

from fleet_client import FleetClient
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


# --- a socket is authorised by who holds it now, not only at its handshake ----------------------------------

ROBOT = "wsa1"
DRIVE = {"type": "drive", "linear": 0.2, "angular": 0.0, "duration_s": 5.0}


def _moved(fleet: FleetClient, start: float, end: float) -> float:
    """Distance between the mean of the first and of the last 5 stored fixes in [start, end] (noise ~2 mm)."""
    rows = list(fleet.history_rows(ROBOT, "position", start=start, end=end))
    assert len(rows) >= 10, f"only {len(rows)} stored fixes in {end - start:.1f} s"

    def mean(part: list[dict[str, Any]]) -> tuple[float, float]:
        return statistics.fmean(r["data"]["x"] for r in part), statistics.fmean(r["data"]["y"] for r in part)

    return math.dist(mean(rows[:5]), mean(rows[-5:]))


async def _until_closed(ws: Any) -> tuple[int, str]:
    """Read (and drop) frames until the server closes the socket -> (code, reason); generous: no timing here."""

    async def drain() -> tuple[int, str]:
        try:
            while True:
                await ws.recv()
        except ConnectionClosed as exc:
            assert exc.rcvd is not None, "closed without a close frame from the server"
            return exc.rcvd.code, exc.rcvd.reason

    return await asyncio.wait_for(drain(), 15)


class Principal:
    """An operator's credential (a token or a browser session) and how an admin takes it away."""

    def __init__(self, server: Any, case: str) -> None:
        self.server, self.case = server, case
        with server.client() as admin:
            if case == "revoke":
                created = admin.post("/api/tokens", json={"name": "ws-revoke", "role": "operator"}).json()
                self.token_id, self.headers = created["id"], {"Authorization": f"Bearer {created['token']}"}
                return
            body = {"username": f"ws-{case}", "password": "ws-password", "role": "operator"}
            assert admin.post("/api/users", json=body).status_code == 201
        with server.client(anonymous=True) as c:
            r = c.post("/api/auth/login", json={"username": body["username"], "password": body["password"]})
            assert r.status_code == 200, r.text
            self.session = r.cookies["fleet_session"]
        self.headers = {"Cookie": f"fleet_session={self.session}"}

    def take_away(self) -> None:
        user = f"/api/users/ws-{self.case}"
        with self.server.client() as admin:
            if self.case == "revoke":
                r = admin.delete(f"/api/tokens/{self.token_id}")
            elif self.case == "disable":
                r = admin.patch(user, json={"disabled": True})
            elif self.case == "demote":
                r = admin.patch(user, json={"role": "viewer"})
            else:
                with self.server.client(anonymous=True) as c:
                    r = c.post("/api/auth/logout", headers={**self.headers, "Origin": self.server.base_url})
        assert r.status_code in (200, 204), r.text


CLOSE_REASONS = {"revoke": "token revoked", "disable": "user disabled", "demote": "role changed to viewer",
                 "logout": "logged out"}  # fmt: skip


@pytest.mark.realtime  # "the robot stopped" is measured in wall-clock windows of its stored positions
def test_taking_a_principal_away_closes_its_sockets_and_stops_the_robot_it_drove(server, spawn_agent):
    """For each way an admin (or the user) takes a principal away: its control socket, driving a robot on a
    5 s set-point, is closed with 1008 and the reason; a set-point sent after the answer never becomes a
    command; the robot stands still 0.6 s later (its deadman alone would have run on for 5 s); the
    principal's other sockets go too, but a demoted operator keeps watching on /ws."""
    spawn_agent(ROBOT, "--disturbances", "--no-current")
    fleet = FleetClient(server.base_url, token=server.token)
    wait_for(lambda: any(r["id"] == ROBOT and r.get("position") for r in fleet.robots()), 60, what="the robot")
    time.sleep(1.0)  # a few of the server's heartbeats (the agent accepts drives under supervision)
    base = _bare(server)

    async def case(who: Principal) -> float:
        kw: dict[str, Any] = {"additional_headers": who.headers, "origin": server.base_url}
        control = await websockets.connect(f"{base}/control/{ROBOT}", **kw)
        other = await websockets.connect(base if who.case != "revoke" else f"{base}/camera/{ROBOT}", **kw)
        await other.send(SUBSCRIBE)
        await control.send(orjson.dumps({**DRIVE, "ref": 1}).decode())
        sent: dict[str, Any] | None = None
        while sent is None:
            sent = next(
                (m for m in orjson.loads(await asyncio.wait_for(control.recv(), 10)) if m["type"] == "sent"), None
            )
        for _ in range(100):  # the robot took it (a set-point delivered late expires and nothing moves)
            status = (await asyncio.to_thread(fleet.command, sent["id"]))["status"]
            if status != "sent":
                break
            await asyncio.sleep(0.1)
        assert status == "accepted", status
        await asyncio.sleep(1.0)
        await asyncio.to_thread(who.take_away)
        taken = time.time()
        with contextlib.suppress(ConnectionClosed):  # after the answer: not one set-point more
            await control.send(orjson.dumps({**DRIVE, "ref": 2}).decode())
        assert await _until_closed(control) == (1008, CLOSE_REASONS[who.case])
        if who.case == "demote":  # a viewer still: the live socket stays and answers
            await other.send(SUBSCRIBE)
            assert orjson.loads(await asyncio.wait_for(other.recv(), 10))[0]["type"] in {
                "snapshot",
                "telemetry",
                "robot",
            }
            await other.close()
        else:
            assert (await _until_closed(other))[0] == 1008
        return taken

    for name in CLOSE_REASONS:
        taken = asyncio.run(case(Principal(server, name)))
        time.sleep(max(0.0, taken + 2.2 - time.time()))
        assert _moved(fleet, taken - 0.8, taken) >= 0.05, f"{name}: the robot never moved: nothing was tested"
        still = _moved(fleet, taken + 0.6, taken + 2.0)
        assert still <= 0.01, f"{name}: the robot ran on {still:.3f} m after its driver was taken away"
        late = [c for c in fleet.commands(ROBOT, start=taken, limit=50) if c["command"] == "drive"]
        assert not late, f"{name}: a set-point sent after the answer was sent to the robot: {late}"
    fleet.close()
