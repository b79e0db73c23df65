"""Live to Foxglove (FLEET_FOXGLOVE_WS): a real server with the setting on and a real simulated robot with
a camera; a WebSocket client speaking the Foxglove protocol sees the robot's channels in the MCAP export's
schemas, subscribes to the pose and camera and receives them. The server offers nothing to write with
(read-only), and is off unless asked for.

The protocol's subprotocol name: foxglove-sdk's server accepts ``foxglove.sdk.v1`` (the same protocol as the
older ``foxglove.websocket.v1``, renamed; a client asking only for the old name gets HTTP 400). The client
here offers both, as current Foxglove and Lichtblick do."""

from __future__ import annotations

import struct
from typing import Any

import orjson
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from websockets.sync.client import ClientConnection, connect

from tests.support.procs import ServerProcess, free_port, wait_for
from tests.support.runs import raw_rows, wait_online

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01


class FoxgloveClient:
    """The client side of the Foxglove WebSocket protocol, as far as a viewer needs it."""

    def __init__(self, port: int) -> None:
        self.ws: ClientConnection = connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, open_timeout=10)
        self.server_info: dict[str, Any] | None = None
        self.channels: dict[str, dict[str, Any]] = {}  # topic -> advertised channel

    def read(self) -> Any:
        raw = self.ws.recv(timeout=20)
        if isinstance(raw, str):
            msg = orjson.loads(raw)
            if msg["op"] == "serverInfo":
                self.server_info = msg
            elif msg["op"] == "advertise":
                for ch in msg["channels"]:
                    self.channels[ch["topic"]] = ch
            return msg
        return raw

    def wait_channels(self, topics: set[str]) -> None:
        while not topics <= set(self.channels):
            self.read()

    def subscribe(self, sub_id: int, topic: str) -> None:
        channel_id = self.channels[topic]["id"]
        request = {"op": "subscribe", "subscriptions": [{"id": sub_id, "channelId": channel_id}]}
        self.ws.send(orjson.dumps(request).decode())  # a text frame: JSON requests are text

    def next_message(self, sub_id: int) -> tuple[int, bytes]:
        """(log time in ns, payload) of the next message of that subscription."""
        while True:
            raw = self.read()
            if isinstance(raw, bytes) and raw[0] == MESSAGE_DATA:
                got_id, log_time = struct.unpack_from("<IQ", raw, 1)
                if got_id == sub_id:
                    return log_time, raw[13:]

    def close(self) -> None:
        self.ws.close()


@pytest.fixture
def foxglove_server(broker, database_url, workdir):
    port = free_port()
    server = ServerProcess(broker, database_url, workdir, FLEET_FOXGLOVE_WS="on", FLEET_FOXGLOVE_WS_PORT=str(port))
    server.start()
    try:
        yield server, port
    finally:
        server.stop()


def test_a_foxglove_client_sees_every_robots_pose_and_camera_live(foxglove_server, spawn_agent):
    server, port = foxglove_server
    spawn_agent("fox-1", "--camera", "--start-pose=0.5,-0.25,0")
    with server.client() as c:
        wait_online(c, ["fox-1"])
    client = FoxgloveClient(port)
    try:
        assert client.ws.subprotocol in SUBPROTOCOLS
        client.read()
        assert client.server_info is not None and client.server_info["op"] == "serverInfo"
        # read-only: no capability to publish, call services or set parameters
        assert not {"clientPublish", "services", "parameters", "parametersSubscribe"} & set(
            client.server_info.get("capabilities") or []
        )
        client.wait_channels({"/fox-1/position", "/fox-1/camera"})
        pose_ch, cam_ch = client.channels["/fox-1/position"], client.channels["/fox-1/camera"]
        assert pose_ch["schemaName"] == "foxglove.PoseInFrame" and pose_ch["encoding"] == "protobuf"
        assert cam_ch["schemaName"] == "foxglove.CompressedImage" and cam_ch["encoding"] == "protobuf"

        client.subscribe(1, "/fox-1/position")
        log_time, payload = client.next_message(1)
        pose = PoseInFrame()
        pose.ParseFromString(payload)
        assert pose.frame_id == "pool"
        assert log_time == pose.timestamp.seconds * 1_000_000_000 + pose.timestamp.nanos
        # it is the robot's own fix, as stored: same time stamp, same place
        with server.client() as c:
            ts = log_time / 1e9
            rows = wait_for(lambda: raw_rows(c, "fox-1", "position", ts - 0.001, ts + 0.001), 10, what="stored fix")
        assert round(rows[0]["ts"] * 1e9) == log_time
        assert pose.pose.position.x == pytest.approx(rows[0]["data"]["x"])
        assert pose.pose.position.y == pytest.approx(rows[0]["data"]["y"])

        client.subscribe(2, "/fox-1/camera")
        _, payload = client.next_message(2)
        image = CompressedImage()
        image.ParseFromString(payload)
        assert image.format == "jpeg" and image.data[:2] == b"\xff\xd8"
    finally:
        client.close()


def test_off_by_default(server):
    """The plain server (no FLEET_FOXGLOVE_WS) opens no Foxglove port."""
    with server.client() as c:
        assert c.get("/api/health").status_code == 200
    assert "Foxglove WebSocket server" not in server.output()
