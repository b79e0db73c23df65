"""Recording camera frames for a run: the server's extra CPU while a run keeps R robots' frames at 5 fps.

R cameras publish 640x480 JPEGs (bench_camera.py's load, ``--fps`` each) through a real broker to the
server; its CPU is measured for ``--seconds`` with no run, then as long again while a run records them
at ``--rate`` frames per second (JPEG files in the frame store). Issue 19's target: 5 fps from 4 robots
costs <= 5 % of a core.

    .venv/bin/python bench/bench_run_frames.py [--robots 4 --fps 15 --rate 5 --seconds 15]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_camera import load_process, render_jpeg
from bench.common import cpu_seconds, report, stack


def run(args: argparse.Namespace) -> dict[str, Any]:
    jpeg = render_jpeg()
    with stack() as (broker, server, _work):
        ctx = mp.get_context("spawn")
        started = ctx.Event()
        total = 2 * args.seconds + 8
        loader = ctx.Process(
            target=load_process, args=(broker.host, broker.port, args.robots, args.fps, total, jpeg, started)
        )
        loader.start()
        started.wait(30)
        time.sleep(2.0)
        pid = server.proc.pid  # type: ignore[union-attr]
        robots = [f"cam-{i}" for i in range(args.robots)]

        def cpu_over(seconds: float) -> float:
            c0, t0 = cpu_seconds(pid), time.monotonic()
            time.sleep(seconds)
            return (cpu_seconds(pid) - c0) / (time.monotonic() - t0)

        baseline = cpu_over(args.seconds)
        with server.client() as c:
            r = c.post("/api/runs", json={"name": "bench", "robots": robots, "frame_rate": args.rate})
            assert r.status_code == 201, r.text
            run_id = r.json()["id"]
            t0 = time.monotonic()
            recording = cpu_over(args.seconds)
            done = c.post(f"/api/runs/{run_id}/stop").json()
            elapsed = time.monotonic() - t0
        loader.join(60)
    return {
        "robots": args.robots,
        "fps": args.fps,
        "rate": args.rate,
        "jpeg_bytes": len(jpeg),
        "cpu_baseline_cores": baseline,
        "cpu_recording_cores": recording,
        "cpu_extra_pct": (recording - baseline) * 100,
        "frames_kept": done["frames"],
        "frames_expected": args.robots * args.rate * elapsed,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=4)
    p.add_argument("--fps", type=float, default=15.0)
    p.add_argument("--rate", type=float, default=5.0)
    p.add_argument("--seconds", type=float, default=15.0)
    args = p.parse_args()
    r = run(args)
    report(
        "run-frames",
        [
            ("server CPU, no run (cores)", f"{r['cpu_baseline_cores']:.3f}", "-", "-"),
            ("server CPU, recording (cores)", f"{r['cpu_recording_cores']:.3f}", "-", "-"),
            (
                "extra CPU (% of a core)",
                f"{r['cpu_extra_pct']:.1f}",
                "<= 5",
                "yes" if r["cpu_extra_pct"] <= 5 else "NO",
            ),
            ("frames kept/expected", f"{r['frames_kept']}/{r['frames_expected']:.0f}", "-", "-"),
        ],
        r,
    )


if __name__ == "__main__":
    main()
