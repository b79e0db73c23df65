"""The twin's robots: each the agent's own motion parts (command handler, motion runner, safety filter, drift
observer) on the honest simulator, with every disturbance on, on the twin's virtual clock.

Nothing of the agent is copied here: :class:`TwinRobot` wires the classes ``robot_agent/agent.py`` wires, with
the simulated motors, and feeds them what the agent's link would (position fixes at the sensor's rate, the
site, the server's heartbeat and the fleet's poses). What it leaves out has no part in a mission's motion: the
camera, the IMU, telemetry batching and the broker.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from pydantic import ValidationError

import robot_agent.motion.commands  # noqa: F401  (registers drive, goto and follow_path)
from fleet_protocol import AVOIDANCE_STREAM, MOTION_COMMANDS, Ack, Command
from robot_agent.commands import CommandHandler
from robot_agent.motion import limits
from robot_agent.motion.collision_guard import GuardedMotors
from robot_agent.motion.kinematics import Kinematics, KinematicsConfig
from robot_agent.motion.neighbours import NeighbourTable
from robot_agent.motion.runner import MotionRunner
from robot_agent.motors.sim import SimMotorDriver
from robot_agent.sim.disturbances import Disturbance, SimDisturbances
from robot_agent.sim.world import Pose, SimWorld

log = logging.getLogger(__name__)

#: the agent's position sensor rate (robot_agent/config.py ``position_rate``)
POSITION_RATE_HZ = 20.0
#: the simulator's integration step in a twin (the agent's is 5 ms; the motors' lag is integrated exactly)
TWIN_STEP_S = 0.01


class TwinClock:
    """``robot_agent.motion.clock.Clock`` on the twin's loop: monotonic is the loop's virtual time, the wall
    clock is ``epoch`` plus it."""

    def __init__(self, loop: asyncio.AbstractEventLoop, epoch: float) -> None:
        self._loop = loop
        self.epoch = epoch

    def monotonic(self) -> float:
        return self._loop.time()

    def now(self) -> float:
        return self.epoch + self._loop.time()

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(seconds)


@dataclass
class FilterLog:
    """What a robot's safety filter did: its interventions (count, seconds) and the nearest it was held at."""

    interventions: int = 0
    seconds: float = 0.0
    neighbours: dict[str, int] = field(default_factory=dict)

    def on_record(self, data: dict[str, Any]) -> None:
        if data.get("event") == "cleared":
            self.interventions += 1
            self.seconds += float(data.get("duration_s") or 0.0)
            who = str(data.get("neighbour") or data.get("cause") or "")
            self.neighbours[who] = self.neighbours.get(who, 0) + 1


def kinematics_config(published: dict[str, Any] | None) -> KinematicsConfig:
    """The agent's ``[kinematics]`` as it published them; its defaults when none or not valid (an agent of
    another version)."""
    try:
        return KinematicsConfig.model_validate(published or {})
    except ValidationError:
        log.warning("rehearsal: kinematics %r not understood: the agent's defaults", published)
        return KinematicsConfig()


class TwinRobot:
    """One robot of the twin. ``on_fix(robot_id, ts, data)``: where its position fixes go (the server's side);
    ``on_ack``: its acks."""

    def __init__(
        self,
        robot_id: str,
        start: Pose,
        *,
        clock: TwinClock,
        seed: int,
        site_payload: bytes,
        on_fix: Callable[[str, float, dict[str, Any]], None],
        on_ack: Callable[[str, Ack], None],
        max_speed_mps: float = 0.3,
        wheel_base_m: float = 0.2,
        kinematics: dict[str, Any] | None = None,
    ) -> None:
        self.robot_id = robot_id
        self.clock = clock
        self._on_fix = on_fix
        self._on_ack = on_ack
        robot_seed = int.from_bytes(hashlib.sha256(f"{seed}:{robot_id}".encode()).digest()[:8], "big")
        self.world = SimWorld(
            start=start,
            max_speed_mps=max_speed_mps,
            wheel_base_m=wheel_base_m,
            clock=clock.monotonic,
            max_step_s=TWIN_STEP_S,
            disturbance=Disturbance(SimDisturbances(disturbances=True, seed=robot_seed), robot_id),
        )
        kin = Kinematics.from_config(kinematics_config(kinematics), wheel_base_m, max_speed_mps)
        self.filter_log = FilterLog()
        self.guard = GuardedMotors(
            SimMotorDriver(self.world),
            kinematics=kin,
            neighbours=NeighbourTable(robot_id),
            emit=self._emit,
            clock=clock,
            server_time=clock.now,
        )
        self.runner = MotionRunner(
            kinematics=kin,
            motors=self.guard,
            send_ack=self._ack,
            emit=self._emit,
            end_drive=lambda reason: self.commands.stop_all(reason),
            driving=lambda: self.commands.driving,
            clock=clock,
        )
        # no motor watchdog thread: the twin's deadman is the command handler's, on the virtual clock
        self.commands = CommandHandler(
            self.guard, self._ack, list(MOTION_COMMANDS), clock=clock.now, watchdog_margin_s=None, motion=self.runner
        )
        self.runner.on_site_payload(site_payload)
        self.fixes = 0

    def _ack(self, ack: Ack) -> None:
        self._on_ack(self.robot_id, ack)

    def _emit(self, stream: str, data: dict[str, Any]) -> None:
        if stream == AVOIDANCE_STREAM:
            self.filter_log.on_record(data)

    def handle(self, cmd: Command) -> None:
        self.commands.handle(cmd)

    def heard_heartbeat(self, server_id: str) -> None:
        self.runner.beats.heard(server_id)

    def hear_poses(self, payload: bytes) -> None:
        self.guard.on_poses_payload(payload)

    def pose(self) -> Pose:
        return self.world.pose()

    def sense(self) -> None:
        """The position sensor's sample: a fix (a control step), none in a dropout."""
        fix = self.world.lighthouse_fix()
        if fix is not None and math.isfinite(fix.x):
            data = {"x": fix.x, "y": fix.y, "z": 0.0, "yaw": fix.yaw}
            self.fixes += 1
            self.runner.on_fix(data)
            self._on_fix(self.robot_id, self.clock.now(), data)

    def tick(self) -> None:
        """The runner's supervision tick, guarded as its own loop guards it (MotionRunner.run)."""
        try:
            self.runner.tick()
        except Exception:
            log.exception("motion supervision failed: motors stopped")
            self.runner.preempt("internal error")
            self.guard.stop()


async def drive(robots: list[TwinRobot], clock: TwinClock) -> None:
    """Every robot's position sensor (``POSITION_RATE_HZ``) and supervision tick (``limits.TICK_S``) on one
    fixed schedule: the agent runs them as tasks of their own, which here would be most of a rehearsal's
    work in the event loop's bookkeeping."""
    per_fix = max(1, round(1.0 / POSITION_RATE_HZ / limits.TICK_S))
    due, k = clock.monotonic(), 0
    while True:
        if k % per_fix == 0:
            for robot in robots:
                robot.sense()
        for robot in robots:
            robot.tick()
        k += 1
        due += limits.TICK_S
        await asyncio.sleep(max(0.0, due - clock.monotonic()))
