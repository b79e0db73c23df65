"""AprilTag detection speed on one core: 640x480 simulated frames with 1-4 tags at 0.4-2.5 m.

Prints, per ``quad_decimate``, frames per second with ``nthreads=1`` and the share of visible tags found
(decimation trades small, distant tags for speed), plus JPEG encoding cost for the camera stream. Frames
get Gaussian sensor noise (``--noise``, default 3 grey levels) because clean synthetic frames are
unrealistically cheap to segment (hundreds of fps at any setting).

    .venv/bin/python bench/bench_apriltag.py [--seconds 2] [--nthreads 1] [--noise 3]

Measured on the 2-core x86 dev/CI machine, noise 3, nthreads=1:
quad_decimate 1.0: 20 fps, 1.5: 55 fps, 2.0: 73 fps, 3.0: 110 fps, 4.0: 216 fps (97 % of tags);
JPEG q80 encode 0.75 ms (27 kB).

Recommendation for a Raspberry Pi 5 (Cortex-A76, roughly 2-3x slower per core than that machine):
``quad_decimate = 2.0`` (the plugin's default) with ``nthreads`` = 4 cores (the default). That keeps
every 0.15 m tag out to 2.5 m and leaves ample headroom over the 10 fps camera (about 25-35 fps on one
core, more with four). Use 1.5 only when tags smaller than ~25 px must be found; 3.0+ only for large,
close tags.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2

from robot_agent.vision.detector import TagDetector
from robot_agent.vision.settings import CaptureSettings
from robot_agent.vision.sim_camera import SimCamera, TagPlacement

TAG_SIZE = 0.15


def _overlapping(quads: list[object]) -> bool:
    """Whether any two tags' boxes (with their white border and a margin) overlap in the image."""
    boxes = []
    for q in quads:
        (x0, y0), (x1, y1) = q.min(axis=0), q.max(axis=0)  # type: ignore[attr-defined]
        mx, my = 0.3 * (x1 - x0), 0.3 * (y1 - y0)
        boxes.append((x0 - mx, y0 - my, x1 + mx, y1 + my))
    return any(
        a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3] for i, a in enumerate(boxes) for b in boxes[i + 1 :]
    )


def make_frames(n: int, noise: float, seed: int = 1) -> list[tuple[Any, int]]:
    """(BGR frame, number of fully visible tags) pairs with 1-4 tags at random distances and angles;
    ``noise`` adds Gaussian sensor noise (grey levels), which makes segmentation work harder."""
    rng = random.Random(seed)
    cam = SimCamera(CaptureSettings(sim_noise=noise))
    frames: list[tuple[Any, int]] = []
    while len(frames) < n:
        tags = []
        for k in range(rng.randint(1, 4)):
            dist = rng.uniform(0.4, 2.5)
            bearing = rng.uniform(-0.45, 0.45)
            oblique = rng.uniform(-0.8, 0.8)
            x, y = dist * math.cos(bearing), dist * math.sin(bearing)
            tags.append(
                TagPlacement.facing(
                    k * 37 + rng.randint(0, 30),
                    TAG_SIZE,
                    x,
                    y,
                    rng.uniform(0.0, 0.3),
                    bearing + math.pi + oblique,
                )
            )
        pose = (0.0, 0.0, 0.0)
        truth = cam.truth(pose, tags)
        if _overlapping([t.corners for t in truth]):
            continue  # a tag hidden behind another would count as missed
        visible = sum(1 for t in truth if t.in_view)
        if visible:
            frames.append((cam.render(pose, tags), visible))
    return frames


def bench(frames: list[tuple[Any, int]], quad_decimate: float, nthreads: int, seconds: float) -> tuple[float, float]:
    det = TagDetector(tag_size_m=TAG_SIZE, nthreads=nthreads, quad_decimate=quad_decimate)
    cam = CaptureSettings().intrinsics()
    grays = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f, _ in frames]
    found = sum(min(len(det.detect(g, cam)), n) for g, (_, n) in zip(grays, frames, strict=True))
    total = sum(n for _, n in frames)
    count, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        det.detect(grays[count % len(grays)], cam)
        count += 1
    fps = count / (time.perf_counter() - t0)
    det.close()
    return fps, found / total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--nthreads", type=int, default=1)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--noise", type=float, default=3.0, help="sensor noise std (grey levels); 0 = clean")
    args = ap.parse_args()
    frames = make_frames(args.frames, args.noise)
    print(
        f"AprilTag detection, 640x480, {len(frames)} frames with 1-4 tag36h11 tags "
        f"({TAG_SIZE} m, 0.4-2.5 m), noise {args.noise:g}, "
        f"nthreads={args.nthreads}, cpu={os.cpu_count()} cores"
    )
    print(f"{'quad_decimate':>13} | {'fps':>7} | {'ms/frame':>8} | tags found")
    print("-" * 48)
    per_qd: dict[str, dict[str, float]] = {}
    for qd in (1.0, 1.5, 2.0, 3.0, 4.0):
        fps, recall = bench(frames, qd, args.nthreads, args.seconds)
        per_qd[f"{qd:g}"] = {"fps": fps, "recall": recall}
        print(f"{qd:>13.1f} | {fps:>7.1f} | {1000.0 / fps:>8.2f} | {100.0 * recall:5.1f} %")
    img = frames[0][0]
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < 1.0:
        cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
        n += 1
    size = len(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])[1])
    print(f"\nJPEG 640x480 q80 encode: {1000.0 * (time.perf_counter() - t0) / n:.2f} ms/frame, {size / 1024:.1f} kB")
    default = per_qd["2"]
    print(
        f"target >= 30 fps on one core at the default quad_decimate 2.0: {default['fps']:.0f} fps "
        f"({'yes' if default['fps'] >= 30 else 'NO'})"
    )
    print(
        "RESULT "
        + json.dumps(
            {
                "bench": "apriltag",
                "nthreads": args.nthreads,
                "fps_qd2": default["fps"],
                "recall_qd2": default["recall"],
                "by_quad_decimate": per_qd,
            }
        )
    )


if __name__ == "__main__":
    main()
