"""Issue 31's A/B for formations: the safety filter must not spoil a formation whose spacing is at least the
safety distance. examples/formation.py (a leader on a looping path, two off-board followers in slots 0.46 m
behind it and 0.6 m apart) on three simulated robots with every disturbance on, ``--runs`` times with the
filter off and on, interleaved (off, on, off, on, ...). Slot errors are measured from the stored positions
(tests/support/formation.py); the figure is each setting's median over its runs of the followers' mean slot
error, and their ratio (target: on within 3 % of off).

    .venv/bin/python bench/bench_formation_filter.py [--runs 3] [--seconds 24]
"""

from __future__ import annotations

import argparse
import asyncio
import math
import statistics
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import report, stack
from examples.formation import LEFT_SLOT, RIGHT_SLOT, circle_path, run_formation
from fleet_client import FleetClient
from fleet_protocol import AvoidanceSettings
from tests.support.formation import formation_errors, slot_start, stored_track
from tests.support.missions import publish_site, wait_ready
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess

RADIUS = 0.7
SETTLE_S = 6.0


def one_run(avoidance: bool, seconds: float) -> dict[str, Any]:
    poses = [
        ("lead", RADIUS, 0.0),
        ("left", *slot_start(LEFT_SLOT, RADIUS)),
        ("right", *slot_start(RIGHT_SLOT, RADIUS)),
    ]
    with stack() as (broker, server, workdir):
        probe = MqttProbe(broker.host, broker.port)
        publish_site(probe, AvoidanceSettings() if avoidance else None)
        agents = [
            AgentProcess(rid, broker, workdir, ["--disturbances", f"--start-pose={x:.3f},{y:.3f},{math.pi / 2:.3f}"])
            for rid, x, y in poses
        ]
        try:
            for a in agents:
                a.start()
            with server.client() as c:
                wait_ready(c, [p[0] for p in poses], timeout=120)
            time.sleep(2.0)
            with FleetClient(server.base_url, token=server.token) as fleet:
                t0 = time.time()
                asyncio.run(run_formation(fleet, "lead", "left", "right", seconds, circle_path(RADIUS)))
                t1 = time.time()
                time.sleep(1.5)

                def track(rid: str) -> tuple[list[float], list[dict[str, Any]]]:
                    return stored_track(fleet, rid, t0 + SETTLE_S, t1)

                lead_ts, lead = track("lead")
                errors = formation_errors(
                    lead_ts, lead, {n: track(n) for n in ("left", "right")}, {"left": LEFT_SLOT, "right": RIGHT_SLOT}
                )
                records = [
                    m["data"] for r in ("left", "right") for m in fleet.history_rows(r, "avoidance", start=t0, end=t1)
                ]
                avoid = len(records)
                causes = Counter(f"{m['cause']}:{m.get('neighbour')}" for m in records if m["event"] == "active")
                near = min((m["distance_m"] for m in records if m.get("distance_m") is not None), default=None)
        finally:
            for a in agents:
                a.stop()
            probe.close()
    means = [statistics.fmean(e) for e in errors.slot.values() if e]
    return {
        "mean_slot_error_m": statistics.fmean(means),
        "avoidance_records": avoid,
        "causes": dict(causes),
        "nearest_m": near,
    }


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--seconds", type=float, default=24.0)
    args = p.parse_args()
    runs: dict[str, list[dict[str, Any]]] = {"off": [], "on": []}
    for _ in range(args.runs):
        for setting in ("off", "on"):
            runs[setting].append(one_run(setting == "on", args.seconds))
            print(setting, runs[setting][-1], flush=True)
    med = {s: statistics.median(r["mean_slot_error_m"] for r in runs[s]) for s in runs}
    ratio = med["on"] / med["off"]
    rows = [
        ("runs each, seconds", f"{args.runs}, {args.seconds:.0f} s", "", ""),
        ("median slot error, filter off", f"{med['off'] * 100:.2f} cm", "", ""),
        ("median slot error, filter on", f"{med['on'] * 100:.2f} cm", "", ""),
        ("on / off", f"{ratio:.3f}", "<= 1.03", "yes" if ratio <= 1.03 else "NO"),
        ("filter records, on (median)", f"{statistics.median(r['avoidance_records'] for r in runs['on'])}", "", ""),
    ]
    report("formation filter", rows, {"runs": runs, "median_m": med, "ratio": ratio})
    return 0


if __name__ == "__main__":
    sys.exit(main())
