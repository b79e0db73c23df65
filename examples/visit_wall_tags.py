"""Visit every wall AprilTag of the site: each robot drives to a point in front of its tags and faces them.

The tags come from the site (``GET /api/site``: each tag's id, size and pose, its ``yaw`` the way its face
looks). A tag's viewing point is ``standoff_m`` in front of its face; the tags are shared out among the
robots (each next tag goes to the robot whose last stop is nearest), and each robot visits its own with
``goto`` (the robot's own controller), one after the other, all robots at once.

    FLEET_URL=http://127.0.0.1:8000 FLEET_TOKEN=... python examples/visit_wall_tags.py r1 r2 [--standoff 0.6]
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
from dataclasses import dataclass
from typing import Any

from fleet_client import CommandFailed, FleetClient, FleetError

#: Failures worth another try: the robot stopped because something went for a moment.
PASSING_FAILURES = frozenset({"link_lost", "no_position", "unsupervised", "stalled"})


@dataclass(frozen=True)
class Viewpoint:
    tag_id: int
    x: float
    y: float
    yaw: float  # the robot's heading there: towards the tag


@dataclass
class Visit:
    robot_id: str
    viewpoint: Viewpoint
    status: str
    reason: str
    command_id: str
    attempts: int = 1


def viewpoints(site: dict[str, Any], standoff_m: float) -> list[Viewpoint]:
    """The point ``standoff_m`` in front of each wall tag, facing it."""
    out = []
    for tag in site.get("tags") or []:
        pose = tag["pose"]
        face = float(pose.get("yaw", 0.0))
        x = float(pose["x"]) + standoff_m * math.cos(face)
        y = float(pose["y"]) + standoff_m * math.sin(face)
        out.append(Viewpoint(int(tag["id"]), x, y, math.atan2(-math.sin(face), -math.cos(face))))
    return out


def share_out(starts: dict[str, tuple[float, float]], points: list[Viewpoint]) -> dict[str, list[Viewpoint]]:
    """Greedy: the nearest (robot's last stop, viewpoint) pair next, until every viewpoint has a robot."""
    plan: dict[str, list[Viewpoint]] = {rid: [] for rid in starts}
    at = dict(starts)
    left = list(points)
    while left:
        rid, vp = min(
            ((r, v) for r in plan for v in left),
            key=lambda rv: math.dist(at[rv[0]], (rv[1].x, rv[1].y)) + 0.5 * len(plan[rv[0]]),
        )
        plan[rid].append(vp)
        at[rid] = (vp.x, vp.y)
        left.remove(vp)
    return plan


def visit_all(
    fleet: FleetClient,
    robots: list[str],
    site: dict[str, Any],
    standoff_m: float = 0.6,
    max_speed: float | None = None,
    tolerance_m: float = 0.05,
    retries: int = 1,
) -> list[Visit]:
    """Every robot visits its share of the tags; returns every visit (done or not) in the order made. A goal
    that failed for a passing reason (the link, the position fix or the server's heartbeat went for a
    moment, or it stalled) is tried again up to ``retries`` times; a refusal (geofence ...) is not."""
    points = viewpoints(site, standoff_m)
    if not points:
        raise FleetError(0, "the site has no wall tags")
    starts = {}
    for rid in robots:
        pos = fleet.robot(rid).get("position")
        if not pos:
            raise FleetError(0, f"robot {rid} has no position fix")
        starts[rid] = (pos["x"], pos["y"])
    plan = share_out(starts, points)
    visits: list[Visit] = []
    lock = threading.Lock()

    def run(rid: str) -> None:
        with FleetClient(fleet.url, fleet.token) as own:  # one HTTP client per thread
            for vp in plan[rid]:
                for attempt in range(1, retries + 2):
                    try:
                        cmd = own.goto(rid, vp.x, vp.y, vp.yaw, tolerance_m=tolerance_m, max_speed=max_speed)
                        visit = Visit(rid, vp, cmd["status"], cmd["reason"], cmd["id"], attempt)
                        break
                    except CommandFailed as exc:  # aborted by a stop, refused ...: on to the next tag
                        visit = Visit(rid, vp, exc.status, exc.reason, str(exc.command.get("id", "")), attempt)
                        if exc.status != "failed" or exc.failure not in PASSING_FAILURES:
                            break
                with lock:
                    visits.append(visit)

    threads = [threading.Thread(target=run, args=(rid,), name=f"visit-{rid}") for rid in robots]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return visits


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("robots", nargs="+")
    p.add_argument("--url")
    p.add_argument("--token")
    p.add_argument("--standoff", type=float, default=0.6, help="metres in front of each tag")
    p.add_argument("--max-speed", type=float, default=None, help="m/s (default: the robot's)")
    args = p.parse_args(argv)
    with FleetClient(args.url, args.token) as fleet:
        try:
            visits = visit_all(fleet, args.robots, fleet.site(), args.standoff, args.max_speed)
        except FleetError as exc:
            print(f"visit_wall_tags: {exc}", file=sys.stderr)
            return 2
    for v in visits:
        where = f"({v.viewpoint.x:.2f}, {v.viewpoint.y:.2f})"
        tries = f" (attempt {v.attempts})" if v.attempts > 1 else ""
        print(f"{v.robot_id}: tag {v.viewpoint.tag_id} at {where}: {v.status} {v.reason}{tries}")
    return 0 if all(v.status == "done" for v in visits) else 1


if __name__ == "__main__":
    sys.exit(main())
