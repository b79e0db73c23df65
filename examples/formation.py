"""A formation: two robots hold a triangle around a leader that follows a path.

The leader runs the path itself (``follow_path``, its own controller on board). Each follower is an
off-board controller (``client.control``) running the formation law of :mod:`fleet_common.formation` (the
same code the server's ``formation`` mission runs): on each of its own poses it takes the leader's latest
pose (the same socket watches the leader), fits the leader's pose, velocity and turn rate, predicts them to
when the set-point will act, and steers to its slot with the slot's velocity and rotation as feed-forward,
a PI pull (the integral is the water current's estimate), as a differential drive. docs/autonomy.md,
"Formation", explains the law and the choices below.

The path and the leader's speed are part of the design, not decoration: the slots are fixed in the leader's
frame, so every jerk of the leader's heading swings each slot by (lever arm x angle). The leader therefore
follows a finely drawn circle (64 points: 5.6 degree corners, which its controller rounds off; 16 points
made 22.5 degree corners that swung a slot 0.46 m behind by 18 cm at once) at 0.08 m/s (at 0.05 m/s its
own path controller, steering back onto the line against a 1-3 cm/s current, wobbles its heading by
several degrees; at 0.1 m/s and more the outer follower, 1.5 x the leader's speed plus its corrections,
runs out of speed headroom).

    FLEET_URL=... FLEET_TOKEN=... python examples/formation.py LEADER LEFT RIGHT [--seconds 60]
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
import time

from fleet_client import ControlError, FleetClient
from fleet_common.formation import FormationGains, LeaderTrack, SlotFollower

#: Slots in the leader's frame (x forward, y left), metres: an isosceles triangle behind the leader.
LEFT_SLOT = (-0.35, 0.3)
RIGHT_SLOT = (-0.35, -0.3)
#: The leader's speed on its path (see the module's docstring for why this one).
LEADER_SPEED_MPS = 0.08
#: Points of the leader's circle: corners small enough that the leader's heading turns smoothly.
PATH_POINTS = 64


def circle_path(
    radius_m: float = 0.7, points: int = PATH_POINTS, cx: float = 0.0, cy: float = 0.0
) -> list[list[float]]:
    """A closed polygon around (cx, cy), counter-clockwise, starting at angle 0."""
    return [
        [cx + radius_m * math.cos(2 * math.pi * i / points), cy + radius_m * math.sin(2 * math.pi * i / points)]
        for i in range(points)
    ]


def path_ahead(path: list[list[float]], x: float, y: float) -> list[list[float]]:
    """The closed ``path`` started at the waypoint after the one nearest (x, y), so that a leader that drifted
    along it while it waited goes on instead of turning back for the first point."""
    if len(path) < 2:
        return path
    near = min(range(len(path)), key=lambda i: math.dist(path[i], (x, y)))
    start = (near + 1) % len(path)
    return path[start:] + path[:start]


async def follow(
    fleet: FleetClient,
    robot: str,
    leader: str,
    offset: tuple[float, float],
    seconds: float,
    gains: FormationGains | None = None,
) -> int:
    """Hold ``robot`` in its slot for ``seconds``; returns the set-points sent. The robot stops at the end."""
    law = SlotFollower(offset, gains or FormationGains())
    track = LeaderTrack(window_s=law.gains.window_s)
    loop = asyncio.get_running_loop()
    deadline = loop.time() + seconds
    steps = 0
    async with fleet.control(robot, watch=[leader]) as ctl:
        async for me in ctl.poses():
            lead = ctl.pose_of(leader)
            if lead is None or "ts" not in lead or me.get("yaw") is None or lead.get("yaw") is None:
                continue
            track.update(float(lead["x"]), float(lead["y"]), float(lead["yaw"]), float(lead["ts"]))
            linear, angular = law.step(
                float(me["x"]), float(me["y"]), float(me["yaw"]), float(me["ts"]), track, time.time()
            )
            await ctl.drive(linear, angular)
            steps += 1
            if loop.time() > deadline:
                break
    return steps


async def run_formation(
    fleet: FleetClient,
    leader: str,
    left: str,
    right: str,
    seconds: float,
    path: list[list[float]] | None = None,
    leader_speed: float = LEADER_SPEED_MPS,
) -> dict[str, int]:
    """Start the leader on its path (looping), hold the formation for ``seconds``, then stop the leader."""
    path = path or circle_path()
    position = fleet.robot(leader).get("position")
    if position:
        path = path_ahead(path, float(position["x"]), float(position["y"]))
    fleet.follow_path(leader, path, tolerance_m=0.05, max_speed=leader_speed, loop=True, wait=False)
    try:
        steps = await asyncio.gather(
            follow(fleet, left, leader, LEFT_SLOT, seconds), follow(fleet, right, leader, RIGHT_SLOT, seconds)
        )
    finally:
        fleet.cancel(leader)
    return {left: steps[0], right: steps[1]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("leader")
    p.add_argument("left")
    p.add_argument("right")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--radius", type=float, default=0.7, help="the leader's circle, metres")
    p.add_argument("--speed", type=float, default=LEADER_SPEED_MPS, help="the leader's speed, m/s")
    p.add_argument("--url")
    p.add_argument("--token")
    args = p.parse_args(argv)
    with FleetClient(args.url, args.token) as fleet:
        try:
            steps = asyncio.run(
                run_formation(
                    fleet, args.leader, args.left, args.right, args.seconds, circle_path(args.radius), args.speed
                )
            )
        except ControlError as exc:
            print(f"formation stopped: {exc}", file=sys.stderr)
            return 1
    print(f"set-points sent: {steps}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
