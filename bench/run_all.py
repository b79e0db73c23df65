"""``make bench``: run every benchmark one after another and print one summary.

Each benchmark is a script that runs alone with its own parameters and ends with a ``RESULT {json}``
line (bench/common.py). ``--quick`` runs each with a small setting (what the test suite smoke-tests);
``--only NAME`` picks some. Figures and the machine go to docs/performance.md.

    .venv/bin/python bench/run_all.py [--quick] [--only live --only camera]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
PY = sys.executable

#: name -> (script, full-run args, quick args)
BENCHMARKS: dict[str, tuple[str, list[str], list[str]]] = {
    "ingest": ("bench_ingest.py", [], ["--seconds", "3", "--robots", "10", "--rate", "50"]),
    "mqtt-parse": ("bench_mqtt_parse.py", [], ["--messages", "2000", "--repeat", "1"]),
    "live": (
        "bench_live.py",
        ["--robots", "100", "--rate", "20", "--clients", "5", "--seconds", "30"],
        ["--robots", "10", "--seconds", "3", "--clients", "2"],
    ),
    "server-memory": (
        "bench_live.py",
        ["--robots", "200", "--rate", "10", "--clients", "1", "--seconds", "20"],
        ["--robots", "20", "--rate", "5", "--clients", "1", "--seconds", "3"],
    ),
    "camera": (
        "bench_camera.py",
        ["--robots", "4", "--fps", "15", "--viewers", "2", "--seconds", "30"],
        ["--robots", "1", "--fps", "5", "--viewers", "1", "--seconds", "3"],
    ),
    "history": ("bench_history.py", [], ["--rows", "20000"]),
    "apriltag": ("bench_apriltag.py", [], ["--seconds", "0.5"]),
    "agent-memory": ("bench_agent_memory.py", [], ["--seconds", "5"]),
    "dashboard": ("bench_dashboard.py", [], ["--robots", "10", "--seconds", "5"]),
    "button": ("bench_button.py", [], ["--robots", "10", "--presses", "5"]),
    "health": ("bench_health.py", [], ["--samples", "500", "--seconds", "5"]),
    "gap-repair": (
        "bench_gap_repair.py",
        [],
        ["--robots", "2", "--rate", "50", "--freeze", "2", "--queue", "20", "--receive-maximum", "10"],
    ),
    "motion": ("bench_motion.py", [], ["--robots", "2", "--goals", "2", "--path-points", "0"]),
    "geofence": ("bench_geofence.py", [], ["--robots", "1", "--attempts", "4"]),
    "offboard": ("bench_offboard.py", [], ["--robots", "2", "--seconds", "3"]),
    "runs-export": ("bench_runs_export.py", [], ["--robots", "2", "--minutes", "0.2", "--frames", "20"]),
    # issue 28: dozens of exports left unread beside live QoS 1 telemetry and /api/health
    "export-stall": ("bench_export_stall.py", [], ["--quick"]),
    "run-frames": ("bench_run_frames.py", [], ["--robots", "1", "--seconds", "2"]),
    "missions": ("bench_missions.py", [], ["--repeat", "1"]),
    "mission-sweep": ("bench_mission_sweep.py", [], ["--size", "1", "--robots", "2"]),
    "mission-sweep-kill": (
        "bench_mission_sweep.py",
        ["--kill-at", "0.4"],
        ["--size", "1", "--robots", "2", "--kill-at", "0.4"],
    ),
    "mission-limits": ("bench_mission_limits.py", [], ["--quick"]),
    # issue 31: six robots on crossing gotos for 5 minutes; the safety filter's cost a control tick
    "collisions": ("bench_collisions.py", [], ["--robots", "2", "--seconds", "10"]),
    "filter-cost": ("bench_filter_cost.py", [], ["--ticks", "50"]),
    # issue 32: the twin's speed on one core, then a rehearsal against its real run (the quick run: the twin only)
    "rehearsal": ("bench_rehearsal.py", [], ["--repeat", "1", "--no-real"]),
    # an hour: its figures are in docs/reliability.md
    "soak": ("bench_soak.py", [], ["--robots", "2", "--minutes", "0.25", "--sample", "1", "--goto-every", "3"]),
}

#: benchmarks whose full run takes longer than the default timeout: seconds to allow them
LONG_RUNS_S = {"soak": 4500.0, "collisions": 900.0}


def run_one(name: str, quick: bool, timeout: float) -> dict[str, object]:
    script, full, small = BENCHMARKS[name]
    path = BENCH / script
    if not path.exists():
        return {"bench": name, "status": "missing", "detail": f"{script} not found"}
    argv = [PY, str(path), *(small if quick else full)]
    t0 = time.monotonic()
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, cwd=BENCH.parent)
    except subprocess.TimeoutExpired:
        return {"bench": name, "status": "timeout", "seconds": timeout}
    elapsed = time.monotonic() - t0
    sys.stdout.write(proc.stdout)
    results = [json.loads(line[len("RESULT ") :]) for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode != 0 or not results:
        tail = (proc.stderr or proc.stdout)[-1500:]
        return {"bench": name, "status": "failed", "returncode": proc.returncode, "detail": tail}
    return {"status": "ok", "wall_s": round(elapsed, 1), **results[-1], "bench": name}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="small settings (seconds, not minutes)")
    p.add_argument("--only", action="append", choices=sorted(BENCHMARKS), help="run just these")
    p.add_argument("--timeout", type=float, default=900.0, help="per benchmark, seconds")
    p.add_argument("--json", type=Path, help="also write all results to this file")
    args = p.parse_args()
    names = args.only or list(BENCHMARKS)
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}")
    results = []
    for name in names:
        print(f"\n=== {name} {'(quick)' if args.quick else ''}", flush=True)
        long_run = 0.0 if args.quick else LONG_RUNS_S.get(name, 0.0)
        results.append(run_one(name, args.quick, max(args.timeout, long_run)))
    print("\nsummary")
    for r in results:
        figures = {k: v for k, v in r.items() if k not in ("bench", "status", "detail") and not isinstance(v, dict)}
        shown = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in figures.items())
        print(f"  {r['bench']:<14} {r['status']:<8} {shown[:300]}")
        if r["status"] != "ok":
            print(f"      {str(r.get('detail', ''))[-400:]}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0 if all(r["status"] in ("ok", "missing") for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
