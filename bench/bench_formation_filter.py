"""Issue 31's A/B for formations: the safety filter must not spoil a formation whose spacing is at least the
safety distance. examples/formation.py (a leader on a looping path, two off-board followers in slots 0.46 m
behind it and 0.6 m apart) on three simulated robots with every disturbance on, ``--runs`` times with the
filter off and on, interleaved (off, on, off, on, ...). Slot errors are measured from the stored positions
(tests/support/formation.py); the figure is each setting's median over its runs of the followers' mean slot
error, and their ratio (target: on within 3 % of off).

    .venv/bin/python bench/bench_formation_filter.py [--runs 3] [--seconds 24] [--twin SEEDS]

``--twin 12``: the same A/B as a ``formation`` mission (the server's law, the same slots and circle) in the
rehearsal twin (docs/missions.md, "Rehearsal"), one seed per run: seconds instead of minutes, for tuning.
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

from backend.services.rehearsal import RehearsalInput, RobotStart, rehearse
from bench.common import report, stack
from examples.formation import LEADER_SPEED_MPS, LEFT_SLOT, RIGHT_SLOT, circle_path, run_formation
from fleet_client import FleetClient
from fleet_protocol import AvoidanceSettings, SiteMessage
from fleet_protocol.motion import default_pool_site
from tests.support.formation import formation_errors, slot_start, stored_track
from tests.support.missions import publish_site, wait_ready
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess
from tests.support.rehearsal import draft

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


def twin_run(avoidance: bool, seconds: float, seed: int) -> dict[str, Any]:
    """One run as a formation mission in the twin; slot errors from its fixes, as from stored ones."""
    starts = [
        RobotStart("lead", RADIUS, 0.0, math.pi / 2),
        RobotStart("left", *slot_start(LEFT_SLOT, RADIUS), math.pi / 2),
        RobotStart("right", *slot_start(RIGHT_SLOT, RADIUS), math.pi / 2),
    ]
    body = {
        "type": "formation",
        "robots": ["lead", "left", "right"],
        "params": {
            "leader": "lead",
            "path": circle_path(RADIUS),
            "slots": {"left": list(LEFT_SLOT), "right": list(RIGHT_SLOT)},
            "speed": LEADER_SPEED_MPS,
            "duration_s": seconds,
        },
    }
    site = SiteMessage(version=1, site=default_pool_site(), avoidance=AvoidanceSettings(enabled=avoidance))
    inp = RehearsalInput(draft(body, starts), site.model_dump(mode="json"), starts, seconds + 30)
    fixes: dict[str, tuple[list[float], list[dict[str, Any]]]] = {r.robot_id: ([], []) for r in starts}

    def tap(robot_id: str, ts: float, data: dict[str, Any]) -> None:
        fixes[robot_id][0].append(ts)
        fixes[robot_id][1].append(dict(data))

    predicted = rehearse(inp, seed, tap)["predicted"]
    lead_ts, lead = fixes["lead"]
    settled = [k for k, t in enumerate(lead_ts) if t >= lead_ts[0] + 1.0 + SETTLE_S]  # the twin's 1 s warm-up
    errors = formation_errors(
        [lead_ts[k] for k in settled],
        [lead[k] for k in settled],
        {n: fixes[n] for n in ("left", "right")},
        {"left": LEFT_SLOT, "right": RIGHT_SLOT},
    )
    return {
        "mean_slot_error_m": statistics.fmean(statistics.fmean(e) for e in errors.slot.values() if e),
        "avoidance_records": predicted["filter_interventions"],
        "nearest_m": predicted["min_separation_m"],
        "seed": seed,
    }


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--seconds", type=float, default=24.0)
    p.add_argument("--twin", type=int, default=0, metavar="SEEDS", help="in the rehearsal twin, this many seeds")
    args = p.parse_args()
    runs: dict[str, list[dict[str, Any]]] = {"off": [], "on": []}
    for i in range(args.twin or args.runs):
        for setting in ("off", "on"):
            on = setting == "on"
            runs[setting].append(twin_run(on, args.seconds, i) if args.twin else one_run(on, args.seconds))
            print(setting, runs[setting][-1], flush=True)
    med = {s: statistics.median(r["mean_slot_error_m"] for r in runs[s]) for s in runs}
    ratio = med["on"] / med["off"]
    rows = [
        (
            "runs each, seconds",
            f"{args.twin or args.runs}, {args.seconds:.0f} s" + (" (twin)" if args.twin else ""),
            "",
            "",
        ),
        ("median slot error, filter off", f"{med['off'] * 100:.2f} cm", "", ""),
        ("median slot error, filter on", f"{med['on'] * 100:.2f} cm", "", ""),
        ("on / off", f"{ratio:.3f}", "<= 1.03", "yes" if ratio <= 1.03 else "NO"),
        ("filter records, on (median)", f"{statistics.median(r['avoidance_records'] for r in runs['on'])}", "", ""),
    ]
    report("formation filter", rows, {"runs": runs, "median_m": med, "ratio": ratio})
    return 0


if __name__ == "__main__":
    sys.exit(main())
