"""The coverage planner's speed: a 200-vertex polygon with 3 keep-outs split for 10 robots (the issue: <= 1 s),
and the whole 4 m x 4 m pool for 3 robots at a 0.2 m sweep. Pure geometry, no processes.

    .venv/bin/python bench/bench_missions.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from shapely.geometry import Point, Polygon, box

from backend.services.missions.coverage import concurrent_clearance, plan_coverage, workable_region
from bench.common import report

SITE = box(-2, -2, 2, 2)
BAND = 0.25  # geofence margin + robot radius


def wavy(n: int = 200) -> Polygon:
    return Polygon(
        [
            (1.7 * (1 + 0.08 * math.sin(5 * a)) * math.cos(a), 1.7 * (1 + 0.08 * math.sin(5 * a)) * math.sin(a))
            for a in (2 * math.pi * i / n for i in range(n))
        ]
    )


def best_of(repeat: int, fn: object) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    keepouts = [Point(0, 0).buffer(0.3), box(0.8, 0.8, 1.1, 1.2), Point(-1, 0.5).buffer(0.2)]

    def hard() -> None:
        plan_coverage(workable_region(wavy(), SITE, keepouts, BAND), 10, 0.2)

    def pool() -> None:
        plan_coverage(workable_region(SITE, SITE, [], BAND), 3, 0.2)

    t_hard, t_pool = best_of(args.repeat, hard), best_of(args.repeat, pool)
    plan = plan_coverage(workable_region(SITE, SITE, [], BAND), 3, 0.2)
    areas = [p.area_m2 for p in plan.parts]
    spread = (max(areas) - min(areas)) / (sum(areas) / len(areas))
    rows = [
        ("200-gon, 3 keep-outs, 10 robots", f"{t_hard * 1000:.0f} ms", "<= 1000 ms", "yes" if t_hard <= 1 else "NO"),
        ("4 m pool, 3 robots, 0.2 m", f"{t_pool * 1000:.0f} ms", "", ""),
        ("pool: part area spread", f"{spread:.1%}", "<= 15 %", "yes" if spread <= 0.15 else "NO"),
        ("pool: concurrent clearance", f"{concurrent_clearance(plan):.2f} m", ">= 0.30 m", ""),
    ]
    report("missions planner", rows, {"hard_s": t_hard, "pool_s": t_pool, "area_spread": spread})


if __name__ == "__main__":
    main()
