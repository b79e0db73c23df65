"""Issue 32's benchmark: a rehearsal's speed and its prediction against the real run.

1. **Speed**: the 3-robot whole-pool sweep (4 m x 4 m at a 0.3 m sweep width) rehearsed in the twin, in this
   process pinned to one core: simulated time over wall time (goal: at least 50), ``--repeat`` times.
2. **Prediction against the real run** (``--real``, the default): real Mosquitto, a real ``fleet-server``
   and three ``fleet-agent --simulate --disturbances``: the same mission rehearsed through
   ``POST /api/missions/{id}/rehearsal`` (its health polled every 50 ms meanwhile: the server must not be
   blocked), then started and run to its end. The predicted duration against the real one (goal: within 15 %),
   the predicted coverage against the server's figure (within 0.03), the closest approach of each.

    .venv/bin/python bench/bench_rehearsal.py [--repeat 3] [--no-real] [--seed 1]
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from backend.services.rehearsal import RobotStart, rehearse
from bench.common import percentile, report, stack
from fleet_client import FleetClient
from tests.support.missions import publish_site, wait_ready
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess
from tests.support.rehearsal import rehearsal_input

STARTS = [RobotStart("rh1", -1.0, -1.5, 1.57), RobotStart("rh2", 0.0, -1.5, 1.57), RobotStart("rh3", 1.0, -1.5, 1.57)]
WIDTH = 0.3


def speed(repeat: int, seed: int) -> list[dict[str, Any]]:
    """The twin alone, on one core."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    body = {"type": "coverage", "robots": [r.robot_id for r in STARTS], "params": {"sweep_width_m": WIDTH}}
    inp = rehearsal_input(body, STARTS, limit_s=3600)
    out = []
    for i in range(repeat):
        result = rehearse(copy.deepcopy(inp), seed + i)
        p = result["predicted"]
        out.append({"simulated_s": p["duration_s"], "wall_s": result["took_s"], "outcome": p["outcome"]})
        print(
            f"twin: {p['duration_s']} s simulated in {result['took_s']} s (x{p['duration_s'] / result['took_s']:.1f})"
        )
    return out


def real(seed: int) -> dict[str, Any]:
    """Rehearse through the server, then run it."""
    with stack() as (broker, server, workdir):
        probe = MqttProbe(broker.host, broker.port)
        publish_site(probe)
        agents = [
            AgentProcess(r.robot_id, broker, workdir, ["--disturbances", f"--start-pose={r.x},{r.y},{r.yaw}"])
            for r in STARTS
        ]
        try:
            for a in agents:
                a.start()
            ids = [r.robot_id for r in STARTS]
            with server.client() as c:
                wait_ready(c, ids, timeout=120)
            with FleetClient(server.base_url, token=server.token, timeout=60) as fleet:
                mid = fleet.create_mission(ids, sweep_width_m=WIDTH, name="bench rehearsal")["id"]
                stop, latencies = threading.Event(), []

                def poll() -> None:
                    with server.client() as c:
                        while not stop.is_set():
                            t0 = time.perf_counter()
                            c.get("/api/health").raise_for_status()
                            latencies.append(time.perf_counter() - t0)
                            stop.wait(0.05)

                poller = threading.Thread(target=poll)
                poller.start()
                asked = time.perf_counter()
                rehearsal = fleet.rehearse_mission(mid, seed=seed)
                answered = time.perf_counter() - asked
                stop.set()
                poller.join()
                fleet.start_mission(mid)
                done = fleet.wait_mission(mid, timeout=900, until=("completed", "failed", "aborted", "paused"))
        finally:
            for a in agents:
                a.stop()
            probe.close()
    p = rehearsal["predicted"]
    return {
        "predicted_s": p["duration_s"],
        "real_s": done["elapsed_s"],
        "predicted_covered": p["covered_fraction"],
        "real_covered": done["covered_fraction"],
        "predicted_closest_m": p["min_separation_m"],
        "real_closest_m": ((done.get("separation") or {}).get("closest") or {}).get("distance_m"),
        "state": done["state"],
        "rehearsal_wall_s": round(answered, 2),
        "twin_s": rehearsal["took_s"],
        "health_p99_ms": round(percentile(latencies, 99) * 1000, 1),
        "health_max_ms": round(max(latencies, default=math.nan) * 1000, 1),
        "health_answers": len(latencies),
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-real", action="store_true", help="the twin's speed only")
    args = ap.parse_args()
    runs = speed(args.repeat, args.seed)
    factor = statistics.median(r["simulated_s"] / r["wall_s"] for r in runs)
    rows = [
        ("rehearsal speed (median), one core", f"x{factor:.1f}", ">= 50", "yes" if factor >= 50 else "NO"),
        ("rehearsal wall time (max)", f"{max(r['wall_s'] for r in runs):.2f} s", "<= 10 s", ""),
    ]
    result: dict[str, Any] = {"twin": runs, "speed_factor": factor}
    if not args.no_real:
        r = real(args.seed)
        result["real"] = r
        duration_err = abs(r["predicted_s"] - r["real_s"]) / r["real_s"]
        cover_err = abs(r["predicted_covered"] - r["real_covered"])
        rows += [
            ("duration predicted / real", f"{r['predicted_s']:.0f} / {r['real_s']:.0f} s", "", ""),
            ("duration error", f"{duration_err:.1%}", "<= 15 %", "yes" if duration_err <= 0.15 else "NO"),
            ("coverage predicted / real", f"{r['predicted_covered']:.3f} / {r['real_covered']:.3f}", "", ""),
            ("coverage error", f"{cover_err:.3f}", "<= 0.03", "yes" if cover_err <= 0.03 else "NO"),
            ("closest predicted / real", f"{r['predicted_closest_m']} / {r['real_closest_m']} m", "", ""),
            ("rehearsal through the API", f"{r['rehearsal_wall_s']:.2f} s", "<= 10 s", ""),
            ("health while rehearsing p99/max", f"{r['health_p99_ms']}/{r['health_max_ms']} ms", "<= 200 ms", ""),
        ]
    report("rehearsal", rows, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
