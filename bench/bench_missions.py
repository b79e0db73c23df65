"""The coverage planner's speed: a 200-vertex polygon with 3 keep-outs split for 10 robots (the issue: <= 1 s),
and the whole 4 m x 4 m pool for 3 robots at a 0.2 m sweep. Then the swept area of a long mission (issue 28):
three robots' tracks of ``--hours`` at 0.15 m/s (a point every 2 cm, as the server samples them), what a step
costs to keep it up to date, and what the union of the whole tracks (a step's work before) cost. Pure
geometry, no processes.

    .venv/bin/python bench/bench_missions.py [--repeat 5] [--hours 1]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from shapely.geometry import LineString, Point, Polygon, box
from shapely.ops import unary_union

from backend.services.missions.coverage import concurrent_clearance, plan_coverage, workable_region
from backend.services.missions.raster import swept_png
from backend.services.missions.state import Coverage, MissionRobot, built_coverage, rings
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
    ap.add_argument("--hours", type=float, default=1.0, help="the long mission's length (its tracks)")
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
    swept_rows, swept = long_mission(args.hours)
    rows += swept_rows
    report("missions planner", rows, {"hard_s": t_hard, "pool_s": t_pool, "area_spread": spread, **swept})


def lanes(x0: float, x1: float, length: float, points: int, rng: np.random.Generator) -> list[list[float]]:
    """A robot's track: lanes of constant x, 0.2 m apart, up and down, a point every 2 cm, ``points`` of them."""
    track: list[list[float]] = []
    x, up = x0, True
    while len(track) < points and x < x1:
        ys = np.arange(0.0, length, 0.02)
        for y in ys if up else ys[::-1]:
            track.append([round(float(x + rng.normal(0, 0.01)), 4), round(float(y), 4)])
        x, up = x + 0.2, not up
    return track[:points]


def long_mission(hours: float) -> tuple[list[tuple[str, str, str, str]], dict[str, Any]]:
    """Three robots sweep their third of a square big enough for ``hours`` at 0.15 m/s and a 0.2 m width."""
    points = int(hours * 3600 * 0.15 / 0.02)
    side = math.sqrt(3 * hours * 3600 * 0.15 * 0.2) + 0.4
    region = box(0, 0, side, side)
    rng = np.random.default_rng(1)
    robots = [
        MissionRobot(
            robot_id=f"r{i}", path=[], breaks=[], track=lanes(i * side / 3 + 0.1, (i + 1) * side / 3, side, points, rng)
        )
        for i in range(3)
    ]
    t0 = time.perf_counter()
    cov = Coverage(rings(region), [], 0.2)
    t_grid = time.perf_counter() - t0
    t0 = time.perf_counter()
    whole = built_coverage(cov, [(r.robot_id, r.track, len(r.track) - 60) for r in robots])
    t_rebuild = time.perf_counter() - t0
    steps, work = [], []
    for k in range(60, 0, -1):  # the last 60 steps: a point more per robot each, as a running mission's step
        view = [
            MissionRobot(robot_id=r.robot_id, path=[], breaks=[], track=r.track[: len(r.track) - k + 1]) for r in robots
        ]
        t0 = time.perf_counter()
        whole.update(view)
        steps.append(time.perf_counter() - t0)
        work.append(whole.work)
    t0 = time.perf_counter()
    outline = whole.view().geometry()  # type: ignore[union-attr]
    t_outline = time.perf_counter() - t0
    t0 = time.perf_counter()
    swept_png(whole.view(), 100.0)
    t_png = time.perf_counter() - t0
    t0 = time.perf_counter()  # before issue 28, every step that saved: the union of the whole tracks' buffers
    strips = {r.robot_id: LineString(r.track).buffer(0.1) for r in robots}
    union = unary_union(list(strips.values())).intersection(region)
    per_robot = {rid: s.intersection(region).area for rid, s in strips.items()}
    t_union = time.perf_counter() - t0
    exact = union.area / region.area
    step_ms = statistics.median(steps) * 1000
    rows = [
        (f"long mission: 3 x {points:,} track points ({hours:g} h), {side:.1f} m square", "", "", ""),
        (
            "  a step's coverage update (median, 1 point per robot)",
            f"{step_ms:.2f} ms",
            "<= 5 ms",
            "yes" if step_ms <= 5 else "NO",
        ),
        ("  points it marks", f"{max(work)}", "3", ""),
        ("  before: union of the whole tracks, per step", f"{t_union * 1000:.0f} ms", "", ""),
        ("  grid at the start (planner pool)", f"{t_grid * 1000:.0f} ms", "", ""),
        ("  grid from whole tracks (pool, once per row read)", f"{t_rebuild * 1000:.0f} ms", "", ""),
        ("  GeoJSON outline / 100 px/m PNG (pool)", f"{t_outline * 1000:.0f} / {t_png * 1000:.0f} ms", "", ""),
        ("  covered: grid vs exact union", f"{whole.fraction:.2%} / {exact:.2%}", "", ""),
    ]
    result = {
        "track_points": points,
        "step_update_ms": step_ms,
        "step_points": max(work),
        "union_before_s": t_union,
        "grid_s": t_grid,
        "rebuild_s": t_rebuild,
        "outline_s": t_outline,
        "png_s": t_png,
        "covered_grid": whole.fraction,
        "covered_exact": exact,
        "outline_m2": outline.area,
        "per_robot_exact_m2": per_robot,
    }
    return rows, result


if __name__ == "__main__":
    main()
