"""WebSocket /ws: snapshot on subscribe, filtered telemetry, command updates, JSON-array text frames."""

from __future__ import annotations

import asyncio
import time

import orjson
import pytest
import websockets

from fleet_protocol import encode_telemetry
from tests.backend.helpers import TOPICS, ProbeRobot, wait_robot, ws_collect


def test_ws_snapshot_and_filtered_telemetry(server, mqtt_probe):
    r1 = ProbeRobot(mqtt_probe, "r1", sensors=("position", "battery"))
    r2 = ProbeRobot(mqtt_probe, "r2")
    r1.status()
    r2.status()
    with server.client() as c:
        wait_robot(c, "r2", lambda r: r["online"])

    def publish() -> None:
        """A burst (no wait per PUBACK), so the server batches several messages per frame."""
        t0 = time.time()
        infos = []
        for i in range(20):
            ts = t0 + i * 0.01
            for robot, stream, data in (
                (r1, "position", {"x": float(i), "y": 1.0, "z": 0.0}),
                (r2, "position", {"x": -1.0, "y": 1.0, "z": 0.0}),
                (r1, "battery", {"volts": 12.0}),
            ):
                topic = TOPICS.telemetry(robot.robot_id, stream)
                infos.append(robot.probe.client.publish(topic, encode_telemetry(i, data, ts), qos=1))
        for info in infos:
            info.wait_for_publish(10)

    def done(msgs):
        return sum(1 for m in msgs if m["type"] == "telemetry") >= 20

    msgs, frames = asyncio.run(
        ws_collect(
            server.ws_url,
            {"type": "subscribe", "robots": ["r1"], "streams": ["position"]},
            done,
            on_open=publish,
        )
    )
    assert msgs[0]["type"] == "snapshot"
    assert [r["id"] for r in msgs[0]["robots"]] == ["r1"]
    assert msgs[0]["estop"]["engaged"] is False
    tel = [m for m in msgs if m["type"] == "telemetry"]
    assert {(m["robot_id"], m["stream"]) for m in tel} == {("r1", "position")}
    assert [m["seq"] for m in tel] == list(range(20))
    assert tel[3]["data"] == {"x": 3.0, "y": 1.0, "z": 0.0, "yaw": None}
    assert len(frames) < len(msgs)  # batched: several messages per frame


def test_ws_all_robots_gets_command_updates(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "r1")
    robot.status()
    with server.client() as c:
        wait_robot(c, "r1", lambda r: r["online"])

    def send() -> None:
        with server.client() as c:
            cmd = c.post("/api/robots/r1/commands", json={"command": "stop", "source": "keyboard"}).json()
        robot.ack(robot.next_command()["id"], "done")
        assert cmd["source"] == "keyboard"

    def done(msgs):
        return any(m["type"] == "command" and m["command"]["status"] == "done" for m in msgs)

    msgs, _ = asyncio.run(
        ws_collect(server.ws_url, {"type": "subscribe", "robots": ["*"], "streams": ["*"]}, done, on_open=send)
    )
    assert msgs[0]["type"] == "snapshot" and msgs[0]["robots"][0]["id"] == "r1"
    statuses = [m["command"]["status"] for m in msgs if m["type"] == "command"]
    assert statuses[0] == "sent" and statuses[-1] == "done"


def test_ws_bad_subscribe_gets_error_and_stays_open(server):
    async def run() -> list[dict]:
        import orjson
        import websockets

        async with websockets.connect(server.ws_url) as ws:
            await ws.send("not json")
            first = orjson.loads(await asyncio.wait_for(ws.recv(), 5))
            await ws.send(orjson.dumps({"type": "subscribe", "robots": ["*"], "streams": ["*"]}).decode())
            second = orjson.loads(await asyncio.wait_for(ws.recv(), 5))
            return [*first, *second]

    msgs = asyncio.run(run())
    assert msgs[0]["type"] == "error" and "subscribe" in msgs[0]["detail"]
    assert msgs[1]["type"] == "snapshot" and msgs[1]["robots"] == []


def test_a_message_over_64_kib_is_refused_by_the_protocol_before_any_handler(server):
    """The handlers take 64 KiB; uvicorn took 16 MiB per message, buffered whole before a handler saw it. Now a
    100 KiB message closes the socket with 1009 (message too big) and no handler answers it."""

    async def scenario() -> tuple[list[dict], int]:
        async with websockets.connect(server.ws_url, max_size=None) as ws:
            await ws.send(" " * (60 * 1024) + "x")  # within the limit: the handler answers (not JSON)
            answer = orjson.loads(await asyncio.wait_for(ws.recv(), 10))
            await ws.send("x" * (100 * 1024))
            with pytest.raises(websockets.ConnectionClosed) as closed:
                await asyncio.wait_for(ws.recv(), 10)
            assert closed.value.rcvd is not None
            return answer, closed.value.rcvd.code

    answer, code = asyncio.run(scenario())
    assert answer[0]["type"] == "error" and answer[0]["detail"].startswith("expected")
    assert code == 1009
