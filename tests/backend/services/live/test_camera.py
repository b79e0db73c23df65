"""Camera relay: a real simulated robot with a rendered camera, frames out over REST and WebSocket."""

from __future__ import annotations

import asyncio
import time

import cv2
import numpy as np
import orjson
import websockets

from fleet_protocol import CameraHeader, Topics, decode_camera_frame, encode_camera_frame
from fleet_protocol.camera import CAMERA_MAGIC
from tests.backend.helpers import ProbeRobot, wait_robot
from tests.support.procs import wait_for

T = Topics()


async def _frames(url: str, count: int, timeout: float = 15.0) -> list[bytes]:
    out: list[bytes] = []
    async with websockets.connect(url, max_size=4 * 1024 * 1024) as ws:
        deadline = time.monotonic() + timeout
        while len(out) < count:
            msg = await asyncio.wait_for(ws.recv(), max(0.1, deadline - time.monotonic()))
            assert isinstance(msg, bytes), "camera frames are binary messages"
            out.append(msg)
    return out


def test_camera_frames_relayed_and_bad_frames_counted(server, spawn_agent, mqtt_probe):
    spawn_agent("cam1", "--camera", "--start-pose=1,0,0")  # faces tag 0 on the east wall
    with server.client() as c:
        wait_robot(c, "cam1", lambda r: "camera" in r["capabilities"]["sensors"], timeout=30)
        r = wait_for(
            lambda: (x := c.get("/api/robots/cam1/camera/latest.jpg")).status_code == 200 and x,
            20,
            what="first frame",
        )
        assert r.headers["content-type"] == "image/jpeg"
        image = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (480, 640, 3)
        seq_rest = int(r.headers["x-frame-seq"])

        frames = asyncio.run(_frames(server.ws_camera_url("cam1"), 5))
        seqs = [decode_camera_frame(f)[0].frame_seq for f in frames]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs) and seqs[-1] > seq_rest
        header, jpeg = decode_camera_frame(frames[-1])
        assert (header.width, header.height) == (640, 480) and jpeg[:2] == b"\xff\xd8"

        # the detections of the apriltag stream refer to frames the viewer has seen
        pts = c.get("/api/robots/cam1/telemetry", params={"stream": "apriltag", "max_points": 50}).json()
        detected = [p for p in pts["points"] if p["data"]["detections"]]
        assert detected and detected[-1]["data"]["detections"][0]["tag_id"] == 0

        # garbage on the camera topic is refused and counted; the relay keeps going
        probe = mqtt_probe()
        probe.publish(T.camera("cam1"), b"not a frame", qos=0)
        huge = encode_camera_frame(CameraHeader(frame_seq=1, ts=time.time(), width=1, height=1), b"x" * 3_000_000)
        probe.publish(T.camera("cam1"), huge, qos=0)
        wait_for(lambda: c.get("/api/stats").json()["rejects"]["by_kind"].get("camera", 0) >= 2, 10, what="rejects")
        before = c.get("/api/stats").json()["camera"]["frames_in"]
        wait_for(lambda: c.get("/api/stats").json()["camera"]["frames_in"] > before + 3, 10, what="more frames")

        assert c.get("/api/robots/nobody/camera/latest.jpg").status_code == 404
        assert orjson.loads(c.get("/api/robots/nobody/camera/latest.jpg").content)["detail"]


def _frame_stamped(ts: str) -> bytes:
    """A camera frame whose header carries ``ts`` as written (the header model refuses to build such a one)."""
    header = f'{{"frame_seq": 1, "ts": {ts}, "width": 1, "height": 1}}'.encode()
    return CAMERA_MAGIC + len(header).to_bytes(4, "big") + header + b"\xff\xd8\xff\xd9"


def test_a_frame_stamped_out_of_range_is_a_counted_reject_without_a_traceback(server, mqtt_probe):
    """A frame stamped 1e300 (or before 1970, or NaN) is refused as a bad frame: counted once, logged in one line,
    never kept. It used to pass, and an open run that keeps frames failed on it with a traceback per frame."""
    robot = ProbeRobot(mqtt_probe, "cam-ts", sensors=("position", "camera"))
    robot.status()
    probe = mqtt_probe()
    with server.client() as c:
        wait_robot(c, "cam-ts", lambda r: r["online"])
        run = c.post("/api/runs", json={"name": "stamps", "robots": ["cam-ts"], "frame_rate": 5})
        assert run.status_code == 201, run.text
        for ts in ("1e300", "-1.0", "NaN"):
            probe.publish(T.camera("cam-ts"), _frame_stamped(ts), qos=1)

        def rejects() -> dict:
            return c.get("/api/stats").json()["rejects"]

        wait_for(lambda: rejects()["by_kind"].get("camera", 0) >= 3, 10, what="three camera rejects")
        assert rejects()["by_kind"]["camera"] == 3
        assert rejects()["by_reason"].get("bad_camera") == 2 and "internal_error" not in rejects()["by_reason"]
        assert c.get("/api/stats").json()["camera"]["frames_in"] == 0
        # a frame stamped now still goes through (the refusals above could have been of every frame)
        probe.publish(T.camera("cam-ts"), _frame_stamped(repr(time.time())), qos=1)
        wait_for(lambda: c.get("/api/stats").json()["camera"]["frames_in"] == 1, 10, what="a good frame")
    assert "Traceback" not in server.output()
