"""The issue's acceptance for coverage missions, end to end: 3 robots sweep the whole 4 m x 4 m pool at a 0.2 m
sweep width (``--size`` makes a smaller square area centred in the pool; the CI-sized run is 1.5 m).

Real Mosquitto, a real ``fleet-server`` (SQLite), real ``fleet-agent --simulate --disturbances`` processes
(current, noise, latency on). Each robot starts where its part's path starts (the bench plans the area with
the server's planner first: the ideal time below has no trip to the part either). Everything is measured from
what the server stored: the robots' positions (telemetry API), the mission's transitions and events.

- **covered**: share of the *sweepable area* (the area minus the band of geofence margin + robot radius along
  the boundary and keep-outs) swept by the stored tracks, each buffered by half the sweep width;
- **mission time**: from the ``draft -> running`` to the ``running -> completed`` transition, against the
  *ideal time* = sweepable area / (robots x width x speed) + turns, where the turns are those of the busiest
  robot's planned path: each corner (>= 10 degrees) costs its angle at the robot's top turn rate
  (``--turn-rate``, 1.5 rad/s, the simulator's kinematic limit), and each lane-to-lane join its length at the
  sweep speed (the joins are path the area formula does not count);
- **closest pair**: the smallest distance between two robots under mission control at the same moment over the
  run (stored fixes; a robot is under mission control until it drops out), and apart from it the closest
  including robots drifting after their dropout (no target: the issue's promise is for robots under control);
- **geofence**: stored fixes leaving the robots' safe region (boundary - margin, keep-outs + margin) while under
  mission control (target 0), and apart from it those of a robot drifting with its motors off after it dropped
  out (a lost link under load, the killed robot), and the robots' own ``geofence`` reports (a motion stopped or
  refused at the fence, an idle robot outside);
- **work**: the area each robot's own track swept, against the mean.

``--kill-at 0.4``: ``kill -9`` of the middle robot's agent once the mission's covered fraction reaches 40 %;
prints the time from the kill to the server's ``replan`` event handing its remaining area to the others, and the
final coverage. Work balance then has no target (the killed robot stopped).

    .venv/bin/python bench/bench_mission_sweep.py [--size 4] [--robots 3] [--width 0.2] [--kill-at 0.4]
        [--avoidance on|off]

``--avoidance off`` publishes the site without the safety filter's settings (robots then run without it): the
A/B of issue 31, "missions are not slowed where nobody is near".
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from shapely.geometry import Polygon, box

from backend.services.missions.coverage import plan_coverage, workable_region
from backend.services.missions.planning import ROBOT_RADIUS_M
from backend.services.missions.state import DEFAULT_SPEED_MPS
from bench.common import report, stack
from fleet_protocol import AvoidanceSettings, default_pool_site
from tests.support.missions import (
    closest_approach,
    coverage_fill,
    fence_crossings,
    path_turns,
    publish_site,
    stored_stream,
    stored_track,
    swept_by_robot,
    wait_ready,
    wait_state,
)
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, wait_for

FENCE_EVENTS = ("stopped", "refused", "outside")


def ideal_time(
    area_m2: float, robots: int, width: float, speed: float, paths: list[list[list[float]]], rate: float
) -> dict[str, float]:
    """area / (robots x width x speed), plus the turns of the busiest robot (see the module docstring)."""
    sweep = area_m2 / (robots * width * speed)
    turns = []
    for path in paths:
        angles = path_turns(path)
        # a join is a leg between two lanes: shorter than a lane, at both ends a corner of ~90 degrees
        legs = [math.dist(a, b) for a, b in itertools.pairwise(path)]
        joins = sum(d for d in legs if d <= 2.5 * width)
        turns.append((sum(angles) / rate + joins / speed, len(angles), joins))
    worst = max(turns, default=(0.0, 0, 0.0))
    return {
        "sweep_s": sweep,
        "turns_s": worst[0],
        "corners": worst[1],
        "joins_m": worst[2],
        "ideal_s": sweep + worst[0],
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=float, default=4.0, help="side of the square area (m); 4 = the whole pool")
    p.add_argument("--robots", type=int, default=3)
    p.add_argument("--width", type=float, default=0.2, help="sweep width (m)")
    p.add_argument("--speed", type=float, default=None, help="m/s; default: the robots' own (0.15)")
    p.add_argument("--turn-rate", type=float, default=1.5, help="rad/s counted per corner in the ideal time")
    p.add_argument("--kill-at", type=float, default=None, help="kill -9 the middle robot at this covered fraction")
    p.add_argument("--timeout", type=float, default=900.0)
    p.add_argument("--tracks", help="write the stored tracks and the plan to this JSON file")
    p.add_argument(
        "--avoidance",
        choices=("on", "off"),
        default="on",
        help="the robots' safety filter (issue 31): on as the server ships it, off for an A/B of its cost",
    )
    args = p.parse_args()
    site = default_pool_site()
    boundary = Polygon(site.boundary)
    whole = args.size >= 4.0
    h = min(args.size, 4.0) / 2
    area = boundary if whole else box(-h, -h, h, h)
    band = site.geofence_margin_m + ROBOT_RADIUS_M
    region = workable_region(area, boundary, [Polygon(k) for k in site.keepouts], band)
    speed = args.speed or DEFAULT_SPEED_MPS
    plan = plan_coverage(region, args.robots, args.width, 0.0, site.min_separation_m)
    ids = [f"sw{i + 1}" for i in range(args.robots)]
    result: dict[str, Any] = {}
    with stack() as (broker, server, workdir):
        probe = MqttProbe(broker.host, broker.port)
        agents: dict[str, AgentProcess] = {}
        try:
            publish_site(probe, AvoidanceSettings() if args.avoidance == "on" else None)
            for rid, part in zip(ids, plan.parts, strict=True):
                (x0, y0), (x1, y1) = part.path[0], part.path[1]
                yaw = math.atan2(y1 - y0, x1 - x0)
                agents[rid] = AgentProcess(
                    rid, broker, workdir, ["--disturbances", f"--start-pose={x0:.3f},{y0:.3f},{yaw:.3f}"]
                )
                agents[rid].start()
            with server.client() as c:
                wait_ready(c, ids, timeout=120)
                body: dict[str, Any] = {"sweep_width_m": args.width}
                if not whole:
                    body["area"] = [list(xy) for xy in area.exterior.coords[:-1]]
                if args.speed:
                    body["speed"] = args.speed
                r = c.post(
                    "/api/missions", json={"type": "coverage", "name": "bench sweep", "robots": ids, "params": body}
                )
                assert r.status_code == 201, r.text
                mid = r.json()["id"]
                r = c.post(f"/api/missions/{mid}/start")
                assert r.status_code == 200, r.text
                started_doc = r.json()
                wall0 = time.time()
                killed_at = None
                victim = ids[len(ids) // 2]
                if args.kill_at is not None:
                    state: dict[str, Any] = {}

                    def reached() -> bool:
                        state["m"] = c.get(f"/api/missions/{mid}").json()
                        assert state["m"]["state"] == "running", (state["m"]["state"], state["m"]["reason"])
                        return bool(state["m"]["covered_fraction"] >= args.kill_at)

                    wait_for(reached, args.timeout, interval=0.3, what=f"{args.kill_at:.0%} covered")
                    killed_at = time.time()  # before: the broker reports it offline as soon as its socket closes
                    agents[victim].kill()
                done = wait_state(c, mid, ("completed", "failed", "paused", "aborted"), timeout=args.timeout)
                wall1 = time.time()
                tracks = {rid: stored_track(c, rid, wall0 - 1, wall1 + 1) for rid in ids}
                fence_reports = [
                    e["data"]
                    for rid in ids
                    for e in stored_stream(c, rid, "geofence", wall0 - 1, wall1 + 1)
                    if e["data"].get("event") in FENCE_EVENTS
                ]
        finally:
            for a in agents.values():
                a.stop()
            probe.close()
    trans = {(t["from_state"], t["to_state"]): t["ts"] for t in done["transitions"]}
    run_s = trans.get(("running", "completed"), wall1) - trans[("draft", "running")]
    paths = [part["path"] for part in started_doc["parts"]]
    ideal = ideal_time(done["workable_area_m2"], len(ids), args.width, speed, paths, args.turn_rate)
    fill = coverage_fill(tracks, region, args.width)
    # under mission control until its dropout; after it the robot's motors are off and it drifts with the current
    released = {
        rid: min((e["ts"] for e in done["events"] if e["kind"] == "dropout" and e["robot_id"] == rid), default=math.inf)
        for rid in ids
    }
    controlled = {rid: [p for p in tr if p[0] < released[rid]] for rid, tr in tracks.items()}
    drifting = {rid: [p for p in tr if p[0] >= released[rid]] for rid, tr in tracks.items()}
    crossings = fence_crossings(controlled, site)
    closest, closest_ts, pa, pb = closest_approach(controlled)  # the promise is for robots under mission control
    any_closest = closest_approach(tracks)[0]  # with a dropped robot drifting: reported, no target
    drift_crossings = fence_crossings(drifting, site)
    work = swept_by_robot(tracks, region, args.width)
    mean = statistics.fmean(work.values())
    spread = max(abs(w - mean) / mean for w in work.values()) if mean > 0 else math.nan
    ratio = run_s / ideal["ideal_s"]
    events = [e["kind"] for e in done["events"]]
    t_start = trans[("draft", "running")]
    for e in done["events"]:  # the timeline, for a look at where time went
        print(
            f"  event {e['ts'] - t_start:7.1f} s {e['kind']:<10} {e['robot_id'] or ''} {e['detail']}", file=sys.stderr
        )
    print(f"  closest: {pa}-{pb} at {closest_ts - t_start:.1f} s", file=sys.stderr)
    if args.tracks:
        Path(args.tracks).write_text(json.dumps({"t0": t_start, "tracks": tracks, "parts": started_doc["parts"]}))
    waits = events.count("wait")
    setting = f"{args.size:g} m square{' (the pool)' if whole else ''}, {len(ids)} robots, {args.width} m, {speed} m/s"
    rows = [
        ("setting", setting, "", ""),
        ("band (geofence margin + robot radius)", f"{band:.2f} m", "", ""),
        ("sweepable area", f"{done['workable_area_m2']:.2f} m2", f"of {area.area:.2f} m2", ""),
        ("end state", done["state"], "completed", "yes" if done["state"] == "completed" else "NO"),
        ("covered (stored positions)", f"{fill:.1%}", ">= 95 %", "yes" if fill >= 0.95 else "NO"),
        ("covered (server's figure)", f"{done['covered_fraction']:.1%}", "", ""),
        ("mission time (running)", f"{run_s:.1f} s", "", ""),
        ("  ideal: area / (n w v)", f"{ideal['sweep_s']:.1f} s", "", ""),
        (
            f"  + turns ({ideal['corners']} corners, {ideal['joins_m']:.2f} m joins)",
            f"{ideal['turns_s']:.1f} s",
            "",
            "",
        ),
        (
            "  ratio to ideal",
            f"{ratio:.2f}",
            "<= 1.3" if args.kill_at is None else "",
            ("yes" if ratio <= 1.3 else "NO") if args.kill_at is None else "",
        ),
        (
            "closest pair under mission control",
            f"{closest:.3f} m",
            f">= {site.min_separation_m} m",
            "yes" if closest >= site.min_separation_m else "NO",
        ),
        ("  closest with a dropped robot drifting", f"{any_closest:.3f} m", "", ""),
        ("geofence: crossings under mission control", f"{crossings}", "0", "yes" if crossings == 0 else "NO"),
        ("  crossings drifting after a dropout (motors off)", f"{drift_crossings}", "", ""),
        ("  the robots' own geofence reports", f"{len(fence_reports)}", "", ""),
        ("separation waits (events)", f"{waits}", "", ""),
    ]
    for rid, w in work.items():
        rows.append(
            (
                f"work {rid} (own track, m2)",
                f"{w:.2f} ({(w - mean) / mean:+.0%})",
                "+-15 %" if killed_at is None else "",
                "",
            )
        )
    if killed_at is None:
        rows.append(("work: worst vs mean", f"{spread:.1%}", "<= 15 %", "yes" if spread <= 0.15 else "NO"))
        takeover = None
    else:
        replans = [e for e in done["events"] if e["kind"] == "replan" and e["robot_id"] == victim]
        takeover = replans[0]["ts"] - killed_at if replans else math.inf
        rows.insert(4, (f"kill -9 of {victim} at", f"{killed_at - wall0:.1f} s", f"{args.kill_at:.0%} covered", ""))
        rows.insert(
            5,
            (
                "  its area re-planned onto the others after",
                f"{takeover:.2f} s",
                "<= 5 s",
                "yes" if takeover <= 5 else "NO",
            ),
        )
    result.update(
        size_m=args.size,
        avoidance=args.avoidance,
        robots=len(ids),
        width_m=args.width,
        speed_mps=speed,
        band_m=band,
        sweepable_m2=done["workable_area_m2"],
        state=done["state"],
        covered=fill,
        server_covered=done["covered_fraction"],
        run_s=run_s,
        ideal_s=ideal["ideal_s"],
        turns_s=ideal["turns_s"],
        ratio=ratio,
        closest_m=closest,
        closest_any_m=any_closest,
        closest_at_s=closest_ts - t_start,
        fence_crossings=crossings,
        drift_crossings=drift_crossings,
        fence_reports=len(fence_reports),
        work_spread=spread,
        waits=waits,
        kill_at=args.kill_at,
        takeover_s=takeover,
    )
    report("mission sweep" + (" (kill)" if killed_at is not None else ""), rows, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
