"""Replay seek: how long a seek anywhere in a run takes until every view of the runs page shows it.

R simulated robots with cameras (real ``fleet-agent --simulate --camera`` processes) are recorded for
``--seconds`` through a real broker and server, one of them driving. The run's page is opened in headless
Chromium and the replay is seeked ``--seeks`` times to random moments (seeded). A seek is timed in the
page from the call to the moment the map's data source has moved, the camera has decoded and drawn the
stored frame of that moment with its AprilTag overlay (GET /api/runs/{id}/frames), and the map has drawn
its next frame (RunReplay.seekAndSettle). Issue 19's target: a replay seek takes <= 200 ms.

    .venv/bin/python bench/bench_replay_seek.py [--robots 3 --seconds 60 --seeks 200]
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import percentile, report, stack
from tests.frontend.conftest import CHROMIUM, CHROMIUM_ARGS
from tests.support.procs import AgentProcess
from tests.support.runs import wait_online

SEEK = """async (times) => {
  const out = [];
  for (const t of times) {
    const t0 = performance.now();
    await window.fleetDebug.replaySeek(t);
    out.push(performance.now() - t0);
  }
  return out;
}"""

FIRST_FRAME = "() => document.querySelector('[data-testid=replay-camera-canvas]').dataset.frameSeq"


def run(args: argparse.Namespace) -> dict[str, Any]:
    from playwright.sync_api import sync_playwright

    ids = [f"seek-{i + 1}" for i in range(args.robots)]
    with stack() as (broker, server, work):
        agents = [
            AgentProcess(rid, broker, work, ["--camera", f"--start-pose={i - 1},0,0"]) for i, rid in enumerate(ids)
        ]
        for a in agents:
            a.start()
        try:
            with server.client() as c:
                wait_online(c, ids, timeout=60)
                run_ = c.post("/api/runs", json={"name": "seek bench", "robots": ids, "frame_rate": 5}).json()
                deadline = time.monotonic() + args.seconds
                while time.monotonic() < deadline:  # keep one robot turning: goals, commands and a moving track
                    c.post(f"/api/robots/{ids[0]}/commands", json={"command": "turn_left", "args": {"duration_s": 1.0}})
                    time.sleep(2.0)
                run_ = c.post(f"/api/runs/{run_['id']}/stop").json()
            rng = random.Random(args.seed)
            times = [rng.uniform(run_["started_at"], run_["ended_at"]) for _ in range(args.seeks)]
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
                context = browser.new_context(viewport={"width": 1280, "height": 900}, **server.browser_auth())
                page = context.new_page()
                t0 = time.monotonic()
                page.goto(f"{server.base_url}/runs/{run_['id']}")
                page.wait_for_function("() => document.querySelector('[data-testid=replay-map]')?.dataset.t")
                page.evaluate("t => window.fleetDebug.replaySeek(t)", (run_["started_at"] + run_["ended_at"]) / 2)
                page.wait_for_function(FIRST_FRAME)
                load_s = time.monotonic() - t0
                page.evaluate(SEEK, times[:5])  # warm-up (JIT, first decodes)
                seeks = page.evaluate(SEEK, times)
                browser.close()
        finally:
            for a in agents:
                a.stop()
    return {
        "robots": args.robots,
        "run_s": run_["ended_at"] - run_["started_at"],
        "frames": run_["frames"],
        "seeks": len(seeks),
        "load_s": load_s,
        "seek_p50_ms": percentile(seeks, 50),
        "seek_p95_ms": percentile(seeks, 95),
        "seek_max_ms": max(seeks),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=3)
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--seeks", type=int, default=200)
    p.add_argument("--seed", type=int, default=19)
    args = p.parse_args()
    r = run(args)
    report(
        "replay-seek",
        [
            ("run recorded (s)", f"{r['run_s']:.1f}", "-", "-"),
            ("frames kept", str(r["frames"]), "-", "-"),
            ("page load and a first frame (s)", f"{r['load_s']:.2f}", "-", "-"),
            ("seek p50 (ms)", f"{r['seek_p50_ms']:.1f}", "-", "-"),
            ("seek p95 (ms)", f"{r['seek_p95_ms']:.1f}", "<= 200", "yes" if r["seek_p95_ms"] <= 200 else "NO"),
            ("seek max (ms)", f"{r['seek_max_ms']:.1f}", "-", "-"),
        ],
        r,
    )


if __name__ == "__main__":
    main()
