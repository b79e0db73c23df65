"""Robots never collide (issue 31): six simulated robots (every disturbance on) on random crossing gotos for
``--seconds`` (default 5 minutes), behind a real server that publishes the fleet's poses. Measured from what the
server stored (the run's summary: the other robot interpolated to each sample's time):

- **closest approach** centre to centre (target >= 0.25 m; bodies are 0.1 m in radius), violations of the
  site's 0.3 m and contacts (0.2 m);
- **goals done** (target >= 95 %), ``failed: blocked`` (held back 10 s without progress), goals ended or
  refused for want of a fix (the simulator's Lighthouse dropouts) and any other end (target: none);
- the safety filters' interventions (count, total time).

The suite runs 60 s of it with the same seed (tests/robot_agent/motion/test_collision_guard.py); the scenario is
tests/support/crossing.py.

    .venv/bin/python bench/bench_collisions.py [--seconds 300] [--robots 6] [--seed 1000] [--twin SEEDS]

``--twin 8 --seconds 60``: the same scenario in the rehearsal twin (bench/twin_crossing.py), seeds ``--seed`` on,
with ``--filter off`` beside it when asked: seconds instead of minutes, deterministic, for tuning the filter.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import report, stack
from bench.twin_crossing import run_twin_crossing
from fleet_client import FleetClient
from tests.backend.helpers import wait_stored
from tests.support.crossing import ring, run_crossing
from tests.support.missions import wait_ready
from tests.support.procs import AgentProcess

CLOSEST_M = 0.25


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--seconds", type=float, default=300.0)
    p.add_argument("--robots", type=int, default=6)
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--twin", type=int, default=0, metavar="SEEDS", help="in the rehearsal twin, this many seeds")
    p.add_argument("--filter", choices=("on", "off"), default="on", help="with --twin: the safety filter")
    args = p.parse_args()
    if args.twin:
        return twin_main(args.robots, args.seconds, args.seed, args.twin, args.filter == "on")
    poses = ring(args.robots)
    ids = [rid for rid, *_ in poses]
    with stack() as (broker, server, workdir):
        agents = [
            AgentProcess(rid, broker, workdir, ["--disturbances", f"--start-pose={x:.3f},{y:.3f},{yaw:.3f}"])
            for rid, x, y, yaw in poses
        ]
        try:
            for a in agents:
                a.start()
            with server.client() as c:
                wait_ready(c, ids, timeout=120)
            time.sleep(2.0)  # heartbeats and the fleet's poses heard
            with FleetClient(server.base_url, token=server.token) as fleet:
                run = fleet._request("POST", "/api/runs", ok=(201,), json={"name": "collisions", "robots": ids})
                run_id = run.json()["id"]
                t0 = time.monotonic()
                crossing = run_crossing(fleet, ids, args.seconds, args.seed)
                wall = time.monotonic() - t0
                stopped = fleet._request("POST", f"/api/runs/{run_id}/stop").json()
                wait_stored(fleet._get, ids, stopped["ended_at"])  # the run's last positions are in its summary
                sep: dict[str, Any] = fleet._get(f"/api/runs/{run_id}")["summary"]["separation"]
        finally:
            for a in agents:
                a.stop()
    results = crossing.results
    done_share = crossing.done / len(results) if results else 0.0
    # the simulator's Lighthouse dropouts end or refuse a goal for want of a fix (a disturbance, as in the suite)
    no_fix = [o for o in results if o.startswith(("failed: no_position", "rejected: no_position"))]
    others = [o for o in results if o != "done" and not o.startswith("failed: blocked") and o not in no_fix]
    closest = sep["closest"]["distance_m"] if sep.get("closest") else float("nan")
    rows = [
        ("robots x seconds", f"{len(ids)} x {wall:.0f} s", "", ""),
        (
            "closest approach (centres)",
            f"{closest:.3f} m",
            f">= {CLOSEST_M} m",
            "yes" if closest >= CLOSEST_M else "NO",
        ),
        ("violations of 0.3 m / contacts", f"{sep['violations']} / {sep['contacts']}", "0 / 0", ""),
        ("goals", f"{len(results)}", "", ""),
        ("done", f"{done_share:.1%}", ">= 95 %", "yes" if done_share >= 0.95 else "NO"),
        ("failed: blocked", f"{crossing.blocked}", "", ""),
        ("no position fix (the simulator's dropouts)", f"{len(no_fix)}", "", ""),
        ("other ends (stall, timeout, silence)", f"{len(others)}", "0", "yes" if not others else "NO"),
        ("interventions (count / s)", f"{sep['interventions']} / {sep['intervention_s']:.0f}", "", ""),
    ]
    report(
        "collisions",
        rows,
        {
            "robots": len(ids),
            "seconds": wall,
            "closest_m": closest,
            "violations": sep["violations"],
            "contacts": sep["contacts"],
            "goals": len(results),
            "done": done_share,
            "blocked": crossing.blocked,
            "no_position": len(no_fix),
            "no_position_ends": sorted(no_fix),
            "other_ends": others,
            "interventions": sep["interventions"],
            "intervention_s": sep["intervention_s"],
        },
    )
    return 0 if closest >= CLOSEST_M and not others else 1  # the done share is judged in the rows


def twin_main(robots: int, seconds: float, seed: int, seeds: int, avoidance: bool) -> int:
    """The crossing in the twin, one run a seed; the goals of all runs counted together."""
    runs = []
    for k in range(seeds):
        run = run_twin_crossing(robots, seconds, seed + k, avoidance)
        runs.append(run)
        print(f"seed {seed + k}", run.figures(), flush=True)
    goals = sum(len(r.results) for r in runs)
    done = sum(r.done for r in runs)
    closest = min(r.closest_m for r in runs)
    others = sorted({o for r in runs for o in r.figures()["other"]})
    rows = [
        ("runs x robots x seconds (twin)", f"{seeds} x {robots} x {seconds:.0f} s", "", ""),
        ("filter", "on" if avoidance else "off", "", ""),
        (
            "closest approach (centres)",
            f"{closest:.3f} m",
            f">= {CLOSEST_M} m",
            "yes" if closest >= CLOSEST_M else "NO",
        ),
        (
            "seconds under 0.3 m / 0.25 m",
            " / ".join(f"{sum(r.under_m[b] for r in runs):.1f}" for b in (0.3, 0.25)),
            "",
            "",
        ),
        ("goals", f"{goals}", "", ""),
        ("done", f"{done / goals:.1%}" if goals else "-", ">= 95 %", "yes" if goals and done / goals >= 0.95 else "NO"),
        ("failed: blocked", f"{sum(r.blocked for r in runs)}", "", ""),
        ("other ends", ", ".join(others) or "none", "", ""),
        ("wall time", f"{sum(r.took_s for r in runs):.1f} s", "", ""),
    ]
    report("collisions (twin)", rows, {"runs": [r.figures() for r in runs], "done": done / goals if goals else None})
    return 0


if __name__ == "__main__":
    sys.exit(main())
