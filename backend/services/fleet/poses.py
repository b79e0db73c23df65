"""The fleet's poses (``{prefix}/poses``): every robot's safety filter keeps clear of its neighbours with them.

- :class:`PoseBoard` keeps each robot's latest position fix, fed by a :class:`TelemetryIngest` tap (robots on
  the old framework come through the same ingest), with the server's monotonic receive time and a velocity
  estimated from the fixes of the last ~0.3 s. The goal check (a ``goto`` into another robot's body) reads it.
- :class:`PosePublisher` publishes them every ``POSES_PERIOD_S`` (QoS 0: a late pose is worthless), each row's
  age counted from when this server heard the fix. Every replica publishes what it heard; robots keep the
  newest fix of each robot. No database on this path: it runs ten times a second.
- The ACL check: a lab that upgrades keeps its old broker ACL, in which robots may not read the topic (or
  the server may not write it). The server listens to its own poses: unheard within ``ACL_CHECK_S`` of
  connecting, it warns once with the lines to add. A robot that reports it hears no poses while this server
  publishes them gives the same warning (the server account may well read its own messages under ``fleet/#``
  while robots may not).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import orjson

from backend.comms.base import Publisher
from backend.core.errors import ServiceError
from backend.core.logging import RateLimitedLogger
from backend.services.fleet.registry import Registry
from fleet_protocol import (
    AVOIDANCE_STREAM,
    BODY_RADIUS_M,
    MAX_POSES,
    POSES_PERIOD_S,
    QOS_POSES,
    PoseRow,
    Topics,
    decode_poses,
)

log = logging.getLogger(__name__)

#: a fix older than this is left out of the poses (the robot is gone, or lost its position)
POSE_MAX_AGE_S = 10.0
#: the velocity is the mean over the fixes of this window (a fix's noise would otherwise be a speed)
VELOCITY_WINDOW_S = 0.3
#: a goal is refused inside another robot's body only where a fix this fresh puts it
GOAL_FIX_FRESH_S = 3.0
#: the server expects to hear its own poses this soon after connecting, else the broker's ACL refuses them
ACL_CHECK_S = 5.0


def acl_lines(topics: Topics) -> str:
    """What an old ACL lacks (docs/upgrading.md): the server writes the poses, every robot reads them."""
    poses = topics.poses()
    return f"'topic readwrite {poses}' under 'user fleet-server' (or its fleet/#) and 'pattern read {poses}'"


@dataclass(slots=True)
class PoseFix:
    """A robot's latest fix as this server heard it (``received``: the server's monotonic clock)."""

    x: float
    y: float
    yaw: float | None
    ts: float
    received: float
    #: how long before ``received`` the robot took it (a backlog sent after a reconnection), when its clock is known
    lag_s: float
    filtered: bool
    vx: float = 0.0
    vy: float = 0.0
    #: (robot ts, x, y) of the fixes in the velocity window
    recent: deque[tuple[float, float, float]] = field(default_factory=lambda: deque(maxlen=64))

    def age(self, now: float) -> float:
        return max(0.0, now - self.received + self.lag_s)


class PoseBoard:
    """Every robot's latest fix and velocity (see the module's docstring). Event loop only."""

    def __init__(
        self, registry: Registry, *, clock: Callable[[], float] = time.monotonic, max_age_s: float = POSE_MAX_AGE_S
    ) -> None:
        self._registry = registry
        self._clock = clock
        self._max_age_s = max_age_s
        self.fixes: dict[str, PoseFix] = {}
        #: robots that reported hearing no poses (the avoidance stream's ``no_poses``): id -> monotonic time
        self.no_poses_reports: dict[str, float] = {}
        self._rl = RateLimitedLogger(log)

    def on_telemetry(self, robot_id: str, stream: str, ts: float, seq: int, data: dict[str, Any]) -> None:
        """The ingest tap: a ``position`` fix updates the robot's row. Never raises into the ingest."""
        try:
            if stream == "position":
                self._on_fix(robot_id, ts, data)
            elif stream == AVOIDANCE_STREAM and data.get("cause") == "no_poses":
                self.no_poses_reports[robot_id] = self._clock()
        except Exception as exc:
            self._rl.warning("tap", "pose board: fix of %s not taken: %r", robot_id[:64], exc)

    def _on_fix(self, robot_id: str, ts: float, data: dict[str, Any]) -> None:
        raw_yaw = data.get("yaw")
        if not _finite(data.get("x"), data.get("y")) or (raw_yaw is not None and not _finite(raw_yaw)):
            return
        x, y, yaw = float(data["x"]), float(data["y"]), None if raw_yaw is None else float(raw_yaw)
        st = self._registry.get(robot_id)
        legacy = st is not None and st.legacy
        # only an agent that says it runs the filter takes its half; an older one is an obstacle, as an old robot
        filtered = st is not None and not legacy and st.collision_filter
        now = self._clock()
        fix = self.fixes.get(robot_id)
        if fix is not None and ts <= fix.ts:
            return  # an older sample (a redelivery, a replayed backlog out of order): not the latest
        lag_s = 0.0
        offset_ms = (st.health or {}).get("clock_offset_ms") if st is not None and not legacy else None
        if isinstance(offset_ms, int | float) and not isinstance(offset_ms, bool):
            lag_s = max(0.0, time.time() - (ts + offset_ms / 1000.0))
        if fix is None:
            fix = self.fixes[robot_id] = PoseFix(x, y, yaw, ts, now, lag_s, filtered)
        else:
            fix.x, fix.y, fix.yaw, fix.ts, fix.received, fix.lag_s = x, y, yaw, ts, now, lag_s
            fix.filtered = filtered
        fix.recent.append((ts, fix.x, fix.y))
        while fix.recent and fix.recent[0][0] < ts - VELOCITY_WINDOW_S:
            fix.recent.popleft()
        t0, x0, y0 = fix.recent[0]
        dt = ts - t0
        fix.vx, fix.vy = ((fix.x - x0) / dt, (fix.y - y0) / dt) if dt > 0 else (0.0, 0.0)

    def robots_without_poses(self, after: float, online_for_s: float) -> list[str]:
        """Robots that said they hear no poses after ``after`` (monotonic), online for ``online_for_s`` by then
        (a robot that just started has not heard any yet)."""
        found = []
        for robot_id, reported in self.no_poses_reports.items():
            st = self._registry.get(robot_id)
            since = None if st is None else st.online_since
            if reported >= after and since is not None and time.time() - since >= online_for_s:
                found.append(robot_id)
        return found

    def fix(self, robot_id: str) -> PoseFix | None:
        return self.fixes.get(robot_id)

    def rows(self, now: float | None = None) -> list[PoseRow]:
        """The rows of a poses message: online robots with a fix of the last ``POSE_MAX_AGE_S``, the freshest
        first, at most ``MAX_POSES``. Forgotten robots and fixes past that age are dropped from the board."""
        now = self._clock() if now is None else now
        aged: list[tuple[float, str, PoseFix]] = []
        for robot_id, fix in list(self.fixes.items()):
            st = self._registry.get(robot_id)
            age = fix.age(now)
            if st is None or age > self._max_age_s:
                del self.fixes[robot_id]
            elif st.online:
                aged.append((age, robot_id, fix))
        aged.sort(key=lambda a: a[0])
        return [
            (rid, f.x, f.y, f.yaw, round(f.vx, 4), round(f.vy, 4), round(age, 3), f.filtered)
            for age, rid, f in aged[:MAX_POSES]
        ]

    def robot_at(
        self, x: float, y: float, *, exclude: str, radius: float = BODY_RADIUS_M, max_age_s: float = GOAL_FIX_FRESH_S
    ) -> tuple[str, float] | None:
        """The nearest other robot whose latest fix (no older than ``max_age_s``) lies within ``radius`` of
        (x, y), with its distance; None when there is none."""
        now = self._clock()
        best: tuple[str, float] | None = None
        for robot_id, fix in self.fixes.items():
            if robot_id == exclude or fix.age(now) > max_age_s:
                continue
            d = math.hypot(fix.x - x, fix.y - y)
            if d <= radius and (best is None or d < best[1]):
                best = (robot_id, d)
        return best

    def refuse_goal_in_body(self, robot_id: str, command: str, args: dict[str, object]) -> None:
        """422 ``goal_inside_robot`` for a ``goto`` whose goal lies inside another robot's body: the robot could
        never reach it (its filter keeps it clear), it would only press on the other one until it gave up."""
        if command != "goto":
            return
        gx, gy = args.get("x"), args.get("y")
        if not isinstance(gx, int | float) or not isinstance(gy, int | float):
            return
        hit = self.robot_at(float(gx), float(gy), exclude=robot_id)
        if hit is not None:
            other, d = hit
            raise ServiceError(
                422,
                f"goto refused: the goal ({gx:.2f}, {gy:.2f}) lies inside robot {other!r}'s body ({d:.2f} m from its "
                f"centre, body radius {BODY_RADIUS_M:g} m); choose a goal clear of it",
                "goal_inside_robot",
            )


def _finite(*values: object) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in values)


class PosePublisher:
    """Publishes the board every ``period_s`` while connected, and checks that the broker lets the poses
    through (see the module's docstring)."""

    def __init__(
        self,
        *,
        board: PoseBoard,
        publisher: Publisher,
        topics: Topics,
        server_id: str,
        period_s: float = POSES_PERIOD_S,
        acl_check_s: float = ACL_CHECK_S,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.board = board
        #: the ``ts`` of each message (a twin's is virtual)
        self._wall = wall
        self._publisher = publisher
        self._topics = topics
        self._topic = topics.poses()
        self.server_id = server_id[:64]
        self._period_s = period_s
        self._acl_check_s = acl_check_s
        self._clock = clock
        self._rl = RateLimitedLogger(log)
        self.sent = 0
        self.rows_sent = 0
        #: our own poses heard back since the current connection (None: not connected)
        self._connected_at: float | None = None
        self._heard_own = False
        self.own_heard = 0
        #: why robots may not hear the poses (the warning logged), None while nothing says so
        self.acl_problem: str | None = None
        self.acl_warnings = 0
        self._warned_robots: set[str] = set()

    def publish_once(self) -> None:
        if not self._publisher.connected:
            return
        rows = self.board.rows()
        payload = orjson.dumps({"server_id": self.server_id, "ts": self._wall(), "seq": self.sent, "robots": rows})
        self._publisher.publish(self._topic, payload, qos=QOS_POSES)
        self.sent += 1
        self.rows_sent += len(rows)

    async def run(self) -> None:
        """On a fixed schedule of the loop's clock, not a sleep after each message: a busy loop's lateness
        does not add up and the rate holds; a slot missed whole is skipped, not sent twice in a burst."""
        loop = asyncio.get_running_loop()
        due = loop.time()
        while True:
            try:
                self.publish_once()
                self.check_acl()
            except Exception as exc:
                self._rl.warning("publish", "publishing the fleet poses failed: %r", exc)
            due += self._period_s
            now = loop.time()
            if due <= now:
                due += math.ceil((now - due) / self._period_s) * self._period_s
            await asyncio.sleep(due - now)

    # -- the ACL check -------------------------------------------------------------------------------------
    def on_connection_change(self, connected: bool) -> None:
        self._connected_at = self._clock() if connected else None
        self._heard_own = False

    def on_poses(self, payload: bytes) -> None:
        """A poses message the broker delivered: ours proves that the server may write and read the topic."""
        poses = decode_poses(payload)  # a bad one is the dispatcher's reject
        if poses.server_id == self.server_id:
            self._heard_own = True
            self.own_heard += 1

    def check_acl(self) -> None:
        """Warn once per connection when our own poses never came back, and once per robot that says it hears
        none while we publish them."""
        now = self._clock()
        since = self._connected_at
        if since is None or now - since < self._acl_check_s:
            return
        if not self._heard_own and self.sent > 0:
            self._heard_own = True  # once per connection
            self._warn(
                f"the broker did not deliver this server's own fleet poses ({self._topic}) within "
                f"{self._acl_check_s:g} s of connecting: its ACL refuses the topic"
            )
        for robot_id in self.board.robots_without_poses(since + self._acl_check_s, self._acl_check_s):
            if robot_id not in self._warned_robots:
                self._warned_robots.add(robot_id)
                self._warn(
                    f"robot {robot_id} hears no fleet poses although this server publishes them on {self._topic}: "
                    "the broker's ACL may not let robots read the topic"
                )

    def _warn(self, why: str) -> None:
        self.acl_problem = why
        self.acl_warnings += 1
        log.warning(
            "%s. Robots then know nothing of their neighbours: they refuse new goals and creep. Add to the "
            "broker's ACL %s (docs/upgrading.md)",
            why,
            acl_lines(self._topics),
        )

    def stats(self) -> dict[str, Any]:
        return {
            "sent": self.sent,
            "rows_sent": self.rows_sent,
            "robots": len(self.board.fixes),
            "own_heard": self.own_heard,
            "acl_warnings": self.acl_warnings,
            "acl_problem": self.acl_problem,
        }
