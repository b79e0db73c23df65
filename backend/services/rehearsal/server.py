"""The server's side of the twin: what the mission service is given instead of the broker, the database and
the other domains. The service itself is the real one (missions/service.py); these only carry its commands
to the twin's robots and their positions back, and record what a live server would store or push.

- :class:`TwinRegistry`: the robots as the registry knows them (online, their latest fix).
- :class:`TwinCommands`: ``create`` checks the args as the command service does (control/args.py) and hands
  the command to the robot's own command handler; the robots' acks set each command's status.
- :class:`TwinBroker`: the fleet poses the real :class:`~backend.services.fleet.poses.PosePublisher` sends,
  delivered to each robot after a link's latency, and lost now and then (QoS 0), from a seeded generator.
- The rest record (the hub: the mission's events) or do nothing (the writer, leases, runs, alarms).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import itertools
import random
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from backend.schemas.commands import CommandCreate
from backend.schemas.robots import CapabilitiesPublic, PositionPublic
from backend.services.control.args import CommandError, checked_args
from backend.services.missions.service import MissionService
from backend.services.rehearsal.robots import TwinRobot
from fleet_protocol import DEFAULT_COMMAND_TTL_S, FINAL_ACK_STATUSES, MOTION_COMMANDS, Ack, Command, Site

#: the fleet poses' way to a robot (s): the broker's and the Wi-Fi's latency, and the share of messages lost
POSES_LATENCY_S = (0.005, 0.03)
POSES_LOSS = 0.02


@dataclass
class TwinRobotState:
    """The registry's fields the mission service and the pose board read."""

    id: str
    online: bool = True
    legacy: bool = False
    collision_filter: bool = True
    hold: None = None
    position: PositionPublic | None = None
    capabilities: CapabilitiesPublic = field(
        default_factory=lambda: CapabilitiesPublic(commands=["stop", *MOTION_COMMANDS])
    )
    health: dict[str, Any] | None = None
    online_since: float | None = 0.0
    config: dict[str, Any] | None = None


class TwinRegistry:
    def __init__(self, robot_ids: list[str]) -> None:
        self.robots = {rid: TwinRobotState(rid) for rid in robot_ids}

    def get(self, robot_id: str) -> TwinRobotState | None:
        return self.robots.get(robot_id)

    def on_fix(self, robot_id: str, ts: float, data: dict[str, Any]) -> None:
        st = self.robots[robot_id]
        st.position = PositionPublic(x=data["x"], y=data["y"], yaw=data.get("yaw"), ts=ts)


@dataclass
class TwinCommand:
    """A command as the mission service reads it back (``cached``)."""

    id: str
    robot_id: str
    command: str
    status: str = "sent"
    reason: str = ""


class TwinCommands:
    """The command service's part the missions use (create, cached, stop_now)."""

    def __init__(self, robots: dict[str, TwinRobot], clock: Callable[[], float]) -> None:
        self._robots = robots
        self._clock = clock
        self._ids = itertools.count(1)
        self.sent: dict[str, TwinCommand] = {}

    async def create(self, robot_id: str, body: CommandCreate, actor: object = None) -> TwinCommand:
        robot = self._robots.get(robot_id)
        if robot is None:
            raise CommandError(404, f"unknown robot {robot_id!r}", "unknown_robot")
        args = checked_args(body.command, body.args)
        cmd = Command(
            id=f"twin-{next(self._ids)}",
            command=body.command,
            args=args,
            ts=self._clock(),
            ttl_s=body.ttl_s or DEFAULT_COMMAND_TTL_S,
        )
        tracked = self.sent[cmd.id] = TwinCommand(cmd.id, robot_id, cmd.command)
        robot.handle(cmd)
        return tracked

    def cached(self, command_id: str) -> TwinCommand | None:
        return self.sent.get(command_id)

    async def stop_now(self, robot_id: str, source: str) -> TwinCommand | None:
        return await self.create(robot_id, CommandCreate(command="stop", source=source))

    def on_ack(self, robot_id: str, ack: Ack) -> None:
        cmd = self.sent.get(ack.id)
        if cmd is None or cmd.status in FINAL_ACK_STATUSES:
            return
        cmd.status, cmd.reason = ack.status.value, ack.reason
        if cmd.command == "drive" and cmd.status in FINAL_ACK_STATUSES:
            del self.sent[ack.id]  # a formation's drives: twenty a second, never read back once ended


class TwinBroker:
    """A :class:`~backend.comms.base.Publisher` that carries the fleet poses to every twin robot."""

    def __init__(self, robots: dict[str, TwinRobot], loop: asyncio.AbstractEventLoop, rng: random.Random) -> None:
        self._robots = robots
        self._loop = loop
        self._rng = rng
        self.lost = 0

    @property
    def connected(self) -> bool:
        return True

    def publish(self, topic: str, payload: bytes | str, qos: int = 1, retain: bool = False) -> bool:
        data = payload.encode() if isinstance(payload, str) else payload
        for robot in self._robots.values():
            if self._rng.random() < POSES_LOSS:
                self.lost += 1
                continue
            self._loop.call_later(self._rng.uniform(*POSES_LATENCY_S), robot.hear_poses, data)
        return True


class TwinHub:
    """The live hub: the mission's events are kept (dropouts, re-plans, blocked legs), the rest dropped."""

    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []

    def publish_control(self, msg: dict[str, Any]) -> None:
        if msg.get("type") == "mission_event":
            self.events.append(msg["event"])


class NullWriter:
    """Nothing of a rehearsal is stored."""

    def submit(self, op: Any, **kwargs: Any) -> concurrent.futures.Future[Any]:
        done: concurrent.futures.Future[Any] = concurrent.futures.Future()
        done.set_result(None)
        return done


class InlinePlanner:
    """Plans and coverage run inline: the twin runs in its own process, and a thread's result would come back
    at a virtual time that depends on the machine's load (the same seed must give the same run)."""

    async def run(self, fn: Callable[..., Any], *args: Any) -> Any:
        return fn(*args)

    async def run_queued(self, fn: Callable[..., Any], *args: Any) -> Any:
        return fn(*args)

    def close(self) -> None:
        pass


class TwinAlarms:
    def critical_kinds(self, robot_id: str) -> list[str]:
        return []

    def raise_(self, *args: Any, **kwargs: Any) -> None:
        pass


class TwinEStop:
    engaged = False


class TwinLeases:
    async def release_mission(self, driver: object) -> None:
        pass

    def forget_mission(self, mission_id: str, why: str) -> None:
        pass


class TwinSite:
    """The site the rehearsal started from (missions/site_source.SiteSource)."""

    def __init__(self, site: Site, version: int) -> None:
        self._site = site
        self._version = version

    def current(self) -> Site:
        return self._site

    def version(self) -> int:
        return self._version


def twin_mission_service(
    *, registry: TwinRegistry, commands: Any, site: TwinSite, hub: TwinHub, server_id: str, clock: Callable[[], float]
) -> MissionService:
    """The server's own mission service on the twin's stand-ins (no database, broker, leases or runs)."""
    return MissionService(
        writer=NullWriter(),  # type: ignore[arg-type]
        hub=hub,  # type: ignore[arg-type]
        registry=registry,  # type: ignore[arg-type]
        commands=commands,
        estop=TwinEStop(),  # type: ignore[arg-type]
        site=site,
        alarms=TwinAlarms(),  # type: ignore[arg-type]
        engine=None,  # type: ignore[arg-type]
        server_id=server_id,
        leases=TwinLeases(),  # type: ignore[arg-type]
        runs=None,  # type: ignore[arg-type]
        planner=InlinePlanner(),  # type: ignore[arg-type]
        clock=clock,
    )
