"""What a robot knows of its neighbours: the newest fix of each, from the servers' ``{prefix}/poses``.

Each server replica publishes the robots it heard; the table keeps, per robot, the fix that is newest (its
time on this robot's monotonic clock: when the message came minus the fix's age). A neighbour is predicted
forward along its measured velocity for the time since that fix (at most :data:`MAX_PREDICT_S`), so a
message that is 0.1 s old does not leave the filter 3 cm behind a robot at full speed.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from fleet_protocol import POSE_STALE_S, ProtocolError, decode_poses
from robot_agent.util import RejectCounter

log = logging.getLogger(__name__)

#: A neighbour is extrapolated along its velocity for at most this long (a stale one is not: it creeps)
MAX_PREDICT_S = POSE_STALE_S
#: A poses message is counted as at most this late: the synchronised clock reads on the late side (half its
#: round trip), which on a loaded machine made fresh fixes look stale and robots creep
MAX_TRANSIT_S = 0.25
#: Robots not heard of for this long are forgotten
FORGET_AFTER_S = 30.0
#: A robot no server listed for this long went offline or was forgotten (a server lists every robot online
#: with a fix of the last 10 s): it is no neighbour any more, not a stale one to creep around
UNLISTED_S = 1.0


@dataclass(slots=True)
class KnownRobot:
    robot_id: str
    x: float
    y: float
    vx: float
    vy: float
    #: this robot's monotonic time of the fix
    fix_at: float
    #: runs the safety filter (takes its half of the avoidance)
    filtered: bool
    #: this robot's monotonic time of the last poses message that listed it
    listed_at: float = -math.inf


@dataclass(frozen=True, slots=True)
class NeighbourView:
    """A neighbour as the filter sees it now: predicted place, velocity, the fix's age."""

    robot_id: str
    x: float
    y: float
    vx: float
    vy: float
    age_s: float
    filtered: bool

    @property
    def stale(self) -> bool:
        return self.age_s > POSE_STALE_S


class NeighbourTable:
    """Fed with ``{prefix}/poses`` payloads; ``own_id`` is left out."""

    def __init__(self, own_id: str) -> None:
        self.own_id = own_id
        self.robots: dict[str, KnownRobot] = {}
        #: this robot's monotonic time of the last poses message (None: none yet)
        self.heard_at: float | None = None
        self.rejects = RejectCounter(log)

    def on_payload(self, payload: bytes, now: float, server_now: float | None = None) -> bool:
        """Take a poses message heard at ``now``; False (counted, logged) when it is not one. ``server_now``:
        the server's clock as this robot knows it (clock sync; None before): the time the message spent on the
        way (a loaded server or broker) is then part of every fix's age."""
        try:
            msg = decode_poses(payload)
        except ProtocolError as exc:
            self.rejects.reject(exc.reason, exc.detail)
            return False
        delay = 0.0 if server_now is None else min(max(server_now - msg.ts, 0.0), MAX_TRANSIT_S)
        self.heard_at = now  # it came: the fleet is known (each fix as old as it is)
        for robot_id, x, y, _yaw, vx, vy, age, filtered in msg.robots:
            if robot_id == self.own_id:
                continue
            fix_at = now - delay - age
            known = self.robots.get(robot_id)
            if known is not None and known.fix_at >= fix_at:
                known.listed_at = max(known.listed_at, now - delay)
                continue  # another replica's older view of it
            self.robots[robot_id] = KnownRobot(robot_id, x, y, vx, vy, fix_at, filtered, now - delay)
        gone = [r for r, k in self.robots.items() if now - k.listed_at > UNLISTED_S or now - k.fix_at > FORGET_AFTER_S]
        for robot_id in gone:
            del self.robots[robot_id]
        return True

    def heard_recently(self, now: float) -> bool:
        """A poses message came in the last :data:`POSE_STALE_S`: the table is worth acting on."""
        return self.heard_at is not None and now - self.heard_at <= POSE_STALE_S

    def silence_s(self, now: float) -> float:
        return math.inf if self.heard_at is None else now - self.heard_at

    def views(self, now: float, x: float, y: float, range_m: float) -> list[NeighbourView]:
        """The neighbours within ``range_m`` of ``(x, y)``, each predicted to ``now``."""
        out = []
        for k in self.robots.values():
            if now - k.listed_at > UNLISTED_S:
                continue
            age = max(0.0, now - k.fix_at)
            dt = min(age, MAX_PREDICT_S)
            px, py = k.x + k.vx * dt, k.y + k.vy * dt
            if (px - x) ** 2 + (py - y) ** 2 > range_m * range_m:
                continue
            out.append(NeighbourView(k.robot_id, px, py, k.vx, k.vy, age, k.filtered))
        return out
