"""Jams unwind by rank: the safety filter's rule for several robots that hold each other still.

Two robots that meet pass on the right (robot_agent/motion/avoidance.py); three or more in a knot can still lock,
each held by another. Then rank decides, as at a junction without lights: a robot that has not moved
:data:`STILL_M` in :data:`STILL_S` while its filter held it back, whose nearest neighbour's id sorts before its
own, gives way: for :data:`GIVE_WAY_S` it backs off from that neighbour, and to the right of it, at
:data:`GIVE_WAY_MPS` (still through the filter). The first robot of any knot is never held by one that waits
for it, so it gets through, and the knot unwinds. A neighbour that does not run the filter (the old framework)
or whose pose is stale, or that is parked, is given way to whatever its id: it will not move aside (a parked
robot only keeps clear: robot_agent/motion/parked.py).
"""

from __future__ import annotations

import math
from collections import deque

from robot_agent.motion.neighbours import NeighbourView

#: held back and still: moved less than STILL_M in the last STILL_S
STILL_S = 1.5
STILL_M = 0.05
#: held back without a break: no tick free for longer than this
HELD_GAP_S = 0.3
#: giving way: this long, this fast (m/s of the look-ahead point)
GIVE_WAY_S = 2.0
GIVE_WAY_MPS = 0.1
#: a neighbour slower than this is parked (a robot with nothing to do never moves, not even aside)
PARKED_MPS = 0.02


class GiveWay:
    def __init__(self, own_id: str) -> None:
        self.own_id = own_id
        self._track: deque[tuple[float, float, float]] = deque()
        self.until = -math.inf
        self.holder: NeighbourView | None = None
        self._held_since = -math.inf
        self._held_at = -math.inf

    def on_pose(self, now: float, x: float, y: float) -> None:
        self._track.append((now, x, y))
        while self._track and now - self._track[0][0] > STILL_S + 0.5:
            self._track.popleft()

    def still(self, now: float) -> bool:
        """Moved less than STILL_M over the last STILL_S (and the track covers that long)."""
        if not self._track or now - self._track[0][0] < STILL_S:
            return False
        _, x, y = self._track[-1]
        return all(math.hypot(px - x, py - y) < STILL_M for t, px, py in self._track if now - t <= STILL_S)

    def held(self, now: float, holder: NeighbourView | None) -> None:
        """The filter held the robot back this tick, ``holder`` nearest: start giving way if it is this
        robot's turn to. Stillness counts only while it is held without a break (a robot that waited, idle,
        before its first command was not stuck)."""
        if now - self._held_at > HELD_GAP_S:
            self._held_since = now
        self._held_at = now
        if holder is None or now < self.until or now - self._held_since < STILL_S or not self.still(now):
            return
        parked = math.hypot(holder.vx, holder.vy) < PARKED_MPS
        if holder.robot_id < self.own_id or not holder.filtered or holder.stale or parked:
            self.until, self.holder = now + GIVE_WAY_S, holder
            self._track.clear()  # it moves now: a new stillness is measured from here

    def velocity(self, now: float, x: float, y: float) -> tuple[float, float] | None:
        """While giving way: the look-ahead point's velocity, away from the holder and to the right of it."""
        if now >= self.until or self.holder is None:
            return None
        dx, dy = x - self.holder.x, y - self.holder.y
        dist = math.hypot(dx, dy)
        if dist < 1e-9:
            return None
        ax, ay = dx / dist, dy / dist  # away from it
        rx, ry = -ay, ax  # facing it, this is to the right
        k = GIVE_WAY_MPS / math.sqrt(2.0)
        return (ax + rx) * k, (ay + ry) * k
