"""Camera relay: R robots x F fps 640x480 JPEG frames through broker and server to B browser-like viewers.

Frames are rendered once (the simulated camera with real AprilTags), JPEG-encoded, and republished with
a fresh header (``ts`` = send time) from a load process over raw MQTT (QoS 0, like the agent). Each viewer
is a WebSocket on ``/ws/camera/{id}`` and records the age of every frame on arrival. "No growing backlog"
is checked by comparing the age in the first and last thirds of the run.

    .venv/bin/python bench/bench_camera.py [--robots 4] [--fps 15] [--viewers 2] [--seconds 15]
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing as mp
import sys
import time
from pathlib import Path
from typing import Any

import orjson

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import cpu_seconds, percentile, report, rss_mb, stack
from bench.rawmqtt import RawPublisher, publish_packet
from fleet_protocol import CameraHeader, decode_camera_frame, encode_camera_frame


def render_jpeg() -> bytes:
    import cv2
    import numpy as np

    from robot_agent.sim.world import Pose, SimWorld
    from robot_agent.vision.settings import CaptureSettings
    from robot_agent.vision.sim_camera import SimCamera, scene_from_world

    scene = scene_from_world(SimWorld(start=Pose(1.0, 0.0, 0.0)))
    frame = SimCamera(CaptureSettings()).render(scene.pose(), scene.tags())
    # sensor noise: a clean synthetic frame compresses to ~9 kB, a real 640x480 camera frame to 30-80 kB
    rng = np.random.default_rng(1)
    frame = np.clip(frame.astype(np.int16) + rng.normal(0, 8, frame.shape), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 80])
    assert ok
    return bytes(buf.tobytes())


def load_process(host: str, port: int, robots: int, fps: float, seconds: float, jpeg: bytes, started: Any) -> None:
    pub = RawPublisher(host, port, "bench-camera-load")
    ids = [f"cam-{i}" for i in range(robots)]
    for rid in ids:
        status = orjson.dumps(
            {
                "online": True,
                "ts": time.time(),
                "agent_version": "bench",
                "capabilities": {"sensors": ["camera"], "commands": []},
            }
        )
        pub.publish(f"fleet/{rid}/status", status, qos=1, retain=True)
    started.set()
    t0 = time.monotonic()
    tick = t0
    seq = 0
    while time.monotonic() - t0 < seconds:
        packets = []
        for rid in ids:
            header = CameraHeader(frame_seq=seq, ts=time.time(), width=640, height=480)
            packets.append(publish_packet(f"fleet/{rid}/camera", encode_camera_frame(header, jpeg)))
        pub.send_many(packets)
        seq += 1
        tick += 1.0 / fps
        time.sleep(max(0.0, tick - time.monotonic()))
    for rid in ids:
        pub.publish(f"fleet/{rid}/status", b"", qos=1, retain=True)
    pub.drain(5)
    pub.close()


async def viewer(url: str, ages: list[tuple[float, float]], stop: asyncio.Event) -> None:
    import websockets

    async with websockets.connect(url, max_size=None) as ws:
        while not stop.is_set():
            try:
                msg = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue
            now = time.time()
            header, _ = decode_camera_frame(msg)  # type: ignore[arg-type]
            ages.append((now, now - header.ts))


async def run(args: argparse.Namespace) -> dict[str, Any]:
    jpeg = render_jpeg()
    with stack() as (broker, server, _work):
        ctx = mp.get_context("spawn")
        started = ctx.Event()
        loader = ctx.Process(
            target=load_process, args=(broker.host, broker.port, args.robots, args.fps, args.seconds + 3, jpeg, started)
        )
        loader.start()
        started.wait(30)
        await asyncio.sleep(1.0)
        stop = asyncio.Event()
        per_viewer: list[list[tuple[float, float]]] = []
        tasks = []
        for v in range(args.viewers):
            for r in range(args.robots):
                ages: list[tuple[float, float]] = []
                per_viewer.append(ages)
                url = server.ws_camera_url(f"cam-{r}")
                tasks.append(asyncio.create_task(viewer(url, ages, stop)))
            del v
        await asyncio.sleep(1.0)
        for ages in per_viewer:
            ages.clear()
        pid = server.proc.pid  # type: ignore[union-attr]
        cpu0, t0 = cpu_seconds(pid), time.monotonic()
        await asyncio.sleep(args.seconds)
        cpu = (cpu_seconds(pid) - cpu0) / (time.monotonic() - t0)
        rss = rss_mb(pid)
        stop.set()
        await asyncio.gather(*tasks, return_exceptions=True)
        loader.join(30)
    all_ages = [a for ages in per_viewer for _, a in ages]
    third = args.seconds / 3
    t_start = min((t for ages in per_viewer for t, _ in ages), default=0.0)
    first = [a for ages in per_viewer for t, a in ages if t < t_start + third]
    last = [a for ages in per_viewer for t, a in ages if t > t_start + 2 * third]
    expected = args.robots * args.viewers * args.fps * args.seconds
    return {
        "robots": args.robots,
        "fps": args.fps,
        "viewers": args.viewers,
        "jpeg_bytes": len(jpeg),
        "age_p50_ms": percentile(all_ages, 50) * 1000,
        "age_p95_ms": percentile(all_ages, 95) * 1000,
        "age_first_third_p50_ms": percentile(first, 50) * 1000,
        "age_last_third_p50_ms": percentile(last, 50) * 1000,
        "frames_received": len(all_ages),
        "frames_expected": expected,
        "server_cpu_cores": cpu,
        "server_rss_mb": rss,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=4)
    p.add_argument("--fps", type=float, default=15.0)
    p.add_argument("--viewers", type=int, default=2)
    p.add_argument("--seconds", type=float, default=15.0)
    args = p.parse_args()
    r = asyncio.run(run(args))
    growing = r["age_last_third_p50_ms"] > 2 * r["age_first_third_p50_ms"] + 20
    report(
        "camera",
        [
            ("frame age p50 (ms)", f"{r['age_p50_ms']:.1f}", "-", "-"),
            ("frame age p95 (ms)", f"{r['age_p95_ms']:.1f}", "<= 100", "yes" if r["age_p95_ms"] <= 100 else "NO"),
            ("backlog growing", "yes" if growing else "no", "no", "NO" if growing else "yes"),
            ("frames received/expected", f"{r['frames_received']}/{r['frames_expected']:.0f}", "-", "-"),
            ("server CPU (cores)", f"{r['server_cpu_cores']:.2f}", "-", "-"),
            ("server RSS (MB)", f"{r['server_rss_mb']:.0f}", "-", "-"),
        ],
        r,
    )


if __name__ == "__main__":
    main()
