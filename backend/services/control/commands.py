"""Commands: validate, record, publish QoS 1 to the robot's cmd topic, track acks, wait for them.

``?wait=S`` semantics: wait up to S seconds for a FINAL ack (done/rejected/expired). If none arrived but
an earlier ack did (e.g. "accepted"), return that latest status with 200. If no ack at all arrived,
the command is marked "timeout" (504); a later ack still updates it.
Commands that get no ack at all within ttl_s + a grace period are marked "timeout" by the sweeper.
Legacy robots cannot ack: the server acks them itself, "accepted" with reason "legacy robot: no ack"; a
velocity ``drive`` reaches them as the nearest seed command (legacy/drive.py), goals are refused (422).
Goals (goto, follow_path) are checked against the current site first: one the geofence refuses is a 422
``geofence`` and never sent; a goto whose goal lies inside another robot's body is a 422 ``goal_inside_robot``.
"""

from __future__ import annotations

import asyncio
import logging
import time

from backend.comms.base import Publisher
from backend.schemas import CommandCreate, CommandPublic
from backend.services.access.audit import Actor, AuditService
from backend.services.control.args import CommandError, checked_args
from backend.services.control.leases import LeaseService
from backend.services.control.tracking import CommandTracking, Tracked
from backend.services.fleet.poses import PoseBoard
from backend.services.fleet.registry import Registry, RobotState
from backend.services.legacy.drive import seed_command_for
from backend.services.legacy.relay import LegacyCommandRelay, LegacyDriveRefused
from backend.services.live.hub import LiveHub
from backend.services.safety.alarms import AlarmService
from backend.services.safety.estop import EStopService
from backend.services.safety.holds import HoldService
from backend.services.site.service import GOAL_COMMANDS, SiteService
from backend.store import repository as repo
from backend.store.writer import BatchWriter
from fleet_protocol import (
    DEFAULT_COMMAND_TTL_S,
    MOVING_COMMANDS,
    QOS_COMMAND,
    AckStatus,
    Command,
    CommandName,
    Topics,
    dumps,
    new_command,
)

log = logging.getLogger(__name__)

LEGACY_ACK_REASON = "legacy robot: no ack"


class CommandService(CommandTracking):
    """Creating and sending commands (their acks, waits and cache: :class:`CommandTracking`)."""

    def __init__(
        self,
        registry: Registry,
        publisher: Publisher,
        topics: Topics,
        writer: BatchWriter,
        hub: LiveHub,
        ack_timeout_grace_s: float = 3.0,
        *,
        estop: EStopService,
        holds: HoldService,
        legacy: LegacyCommandRelay,
        leases: LeaseService,
        audit: AuditService,
        site: SiteService,
        alarms: AlarmService | None = None,
        poses: PoseBoard | None = None,
    ) -> None:
        self._poses = poses
        self._site = site
        self._alarms = alarms
        self._stopping: set[asyncio.Task[object]] = set()
        if alarms is not None:
            alarms.on_raise(self._stop_on_critical_battery)
        self._leases = leases
        self._audit = audit
        self._estop = estop
        self._holds = holds
        self._legacy = legacy
        self._registry = registry
        self._publisher = publisher
        self._topics = topics
        self._writer = writer
        self._hub = hub
        super().__init__(writer=writer, hub=hub, ack_timeout_grace_s=ack_timeout_grace_s)

    # -- creation ----------------------------------------------------------------------------------------
    def validate(self, robot_id: str, body: CommandCreate) -> tuple[RobotState, dict[str, object]]:
        st = self._registry.get(robot_id)
        if st is None:
            raise CommandError(404, f"unknown robot {robot_id!r}", "unknown_robot")
        if not st.online:
            raise CommandError(409, f"robot {robot_id!r} is offline", "robot_offline")
        if not self._publisher.connected:
            raise CommandError(503, "the server is not connected to the MQTT broker", "broker_unavailable")
        if st.legacy and body.command in GOAL_COMMANDS:
            raise CommandError(
                422,
                f"robot {robot_id!r} runs the old Mollusca framework: it cannot run {body.command!r} (no "
                "position control on board); drive it with drive or the seed's commands",
                "unsupported_by_legacy",
            )
        legacy_drive = st.legacy and body.command == "drive"  # mapped to the nearest seed command
        if body.command not in st.capabilities.commands and not legacy_drive:
            supported = ", ".join(st.capabilities.commands) or "none"
            raise CommandError(
                422,
                f"command {body.command!r} is not supported by robot {robot_id!r} (supported: {supported})",
                "unsupported_command",
            )
        if body.command in MOVING_COMMANDS:
            self._refuse_if_latched(st)
        return st, checked_args(body.command, body.args)

    def _refuse_if_latched(self, st: RobotState) -> None:
        """Drives never go out while the fleet e-stop or the robot's hold is latched (stop always passes).
        The robot refuses them too; refusing here means no client ever sees a 202 for such a drive."""
        if self._estop.engaged:
            raise CommandError(409, self._estop.refusal(), code="estop_engaged")
        alarm = self._alarms.blocks_drive(st.id) if self._alarms is not None else None
        if alarm is not None:
            raise CommandError(409, alarm, code="battery_critical")
        blocking = self._holds.blocking(st, self._registry.legacy_unit(st))
        if blocking is not None:
            rid, hold = blocking
            whose = "robot" if rid == st.id else f"robot {rid!r}, which shares its legacy command topic,"
            why = f": {hold.reason}" if hold.reason else ""
            raise CommandError(
                409, f"{whose} is held by {hold.source or 'unknown'}{why}; release the hold to drive", code="robot_held"
            )

    def _stop_on_critical_battery(self, robot_id: str, kind: str) -> None:
        """A robot whose battery goes critical is stopped at once; its drives are refused while the alarm is
        open (blocks_drive)."""
        if kind != "battery_critical":
            return
        task = asyncio.get_running_loop().create_task(self.stop_now(robot_id, "battery critical"))
        self._stopping.add(task)
        task.add_done_callback(self._stopping.discard)

    async def stop_now(self, robot_id: str, source: str) -> CommandPublic | None:
        """Send ``stop`` to an online robot (a hold, or a tool). None when the robot is not online."""
        st = self._registry.get(robot_id)
        if st is None or not st.online or CommandName.STOP not in st.capabilities.commands:
            return None
        return await self.create(robot_id, CommandCreate(command=CommandName.STOP, source=source))

    async def create(self, robot_id: str, body: CommandCreate, actor: Actor | None = None) -> CommandPublic:
        """``actor``: who sends it (a caller of the API): a command that can move the robot needs their
        control lease, and every command is in the audit trail. None: the server's own (a hold's stop)."""
        st, args = self.validate(robot_id, body)
        site_version = await self._site.check_goal(body.command, args) if body.command in GOAL_COMMANDS else None
        if self._poses is not None:  # a goto into another robot's body: 422 goal_inside_robot
            self._poses.refuse_goal_in_body(robot_id, body.command, args)
        if actor is not None and body.command in MOVING_COMMANDS:
            for rid in self._registry.legacy_unit(st) or [robot_id]:  # every robot it moves (a legacy unit)
                await self._leases.drive(rid, actor)
            st, args = self.validate(robot_id, body)  # the world may have changed while we waited
        cmd = new_command(body.command, args, body.ttl_s or DEFAULT_COMMAND_TTL_S)
        public = CommandPublic(
            id=cmd.id,
            robot_id=robot_id,
            command=cmd.command,
            args=cmd.args,
            source=body.source,
            ts=cmd.ts,
            ttl_s=cmd.ttl_s,
            status="sent",
            reason="",
            acks=[],
        )
        tracked = Tracked(public)
        self._remember(tracked)
        row = public.model_dump(exclude={"acks"})
        row["updated_at"] = cmd.ts
        # Published without waiting for its row: the commit queues behind telemetry batches and the
        # rollup's transactions, and waiting for it was most of the round trip's p99 under load. Nothing is
        # lost by not waiting: an ack that overtakes the commit finds the command in this cache and its
        # update queues behind the insert (one FIFO writer); another replica retries it until the row is
        # there (see _from_writer); reads merge this cache in (cached(), overlay()).
        self._send(st, robot_id, cmd, public, tracked)
        self._writer.submit(repo.insert_command(row), after_rows=False)
        if actor is not None:
            detail: dict[str, object] = {"id": cmd.id, "command": cmd.command, "source": body.source}
            if site_version is not None:  # a goal: the site version it was checked against
                detail["site_version"] = site_version
                self._leases.hold_for_goal(robot_id, actor, cmd.id)  # not lapsing mid-motion
            self._audit.record(actor, "command", robot_id, detail)
        return public.model_copy(deep=True)

    def _send(self, st: RobotState, robot_id: str, cmd: Command, public: CommandPublic, tracked: Tracked) -> None:
        """Publish the command (legacy robots: the plain string, acked "accepted" here) and tell live clients."""
        if st.legacy:
            seed = cmd.command
            if seed == "drive":
                seed = seed_command_for(float(cmd.args["linear"]), float(cmd.args["angular"]))
            if seed == CommandName.STOP:
                self._legacy.stop(st)
            else:
                try:
                    self._legacy.drive(st, seed, float(cmd.args["duration_s"]))
                except LegacyDriveRefused as exc:  # the last guard: validate() refused it already
                    log.error("legacy drive %s to %s not sent: %s", cmd.command, robot_id, exc)
                    raise CommandError(409, self._estop.refusal(), code="estop_engaged") from None
            self._hub.publish_control({"type": "command", "command": public.model_dump(mode="json")}, robot_id)
            reason = LEGACY_ACK_REASON if seed == cmd.command else f"{LEGACY_ACK_REASON}; sent as {seed!r}"
            self._apply_ack(tracked, AckStatus.ACCEPTED, reason, time.time(), time.time(), no_more=True)
        else:
            self._publisher.publish(self._topics.cmd(robot_id), dumps(cmd), qos=QOS_COMMAND)
            self._hub.publish_control({"type": "command", "command": public.model_dump(mode="json")}, robot_id)
