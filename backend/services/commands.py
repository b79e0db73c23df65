"""Commands: validate, record, publish QoS 1 to the robot's cmd topic, track acks, wait for them.

``?wait=S`` semantics: wait up to S seconds for a FINAL ack (done/rejected/expired). If none arrived but
an earlier ack did (e.g. "accepted"), return that latest status with 200. If no ack at all arrived,
the command is marked "timeout" (504); a later ack still updates it.
Commands that get no ack at all within ttl_s + a grace period are marked "timeout" by the sweeper.
Legacy robots cannot ack: the server acks them itself, "accepted" with reason "legacy robot: no ack".
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import functools
import logging
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

from pydantic import BaseModel, ValidationError

from backend.core.metrics import Histogram
from backend.schemas import AckPublic, CommandCreate, CommandPublic
from backend.services.hub import LiveHub
from backend.services.publisher import Publisher
from backend.services.registry import Registry, RobotState
from backend.store import repository as repo
from backend.store.writer import BatchWriter
from fleet_protocol import (
    DEFAULT_COMMAND_TTL_S,
    DRIVE_COMMANDS,
    FINAL_ACK_STATUSES,
    LEGACY_COMMAND_TOPIC,
    QOS_COMMAND,
    Ack,
    AckStatus,
    CommandName,
    DriveArgs,
    StopArgs,
    Topics,
    dumps,
    legacy_namespaced_command_topic,
    new_command,
)

log = logging.getLogger(__name__)

LEGACY_ACK_REASON = "legacy robot: no ack"
ARG_MODELS: dict[str, type[BaseModel]] = {
    **{c: DriveArgs for c in DRIVE_COMMANDS},
    CommandName.STOP: StopArgs,
}
CACHE_MAX = 5000


class CommandError(Exception):
    def __init__(self, status_code: int, detail: str) -> None:
        super().__init__(detail)
        self.status_code = status_code
        self.detail = detail


@dataclass
class Tracked:
    cmd: CommandPublic
    final: asyncio.Event = field(default_factory=asyncio.Event)


def _format_errors(exc: ValidationError) -> str:
    parts = []
    for e in exc.errors(include_url=False, include_input=False):
        loc = ".".join(str(p) for p in e["loc"]) or "args"
        parts.append(f"{loc}: {e['msg']}")
    return "; ".join(parts)


class CommandService:
    def __init__(
        self,
        registry: Registry,
        publisher: Publisher,
        topics: Topics,
        writer: BatchWriter,
        hub: LiveHub,
        ack_timeout_grace_s: float = 3.0,
    ) -> None:
        self._registry = registry
        self._publisher = publisher
        self._topics = topics
        self._writer = writer
        self._hub = hub
        self._grace = ack_timeout_grace_s
        self._cache: OrderedDict[str, Tracked] = OrderedDict()
        self.unknown_acks = 0
        #: seconds from the command's creation to each ack, by ack status (for /metrics)
        self.latency = Histogram()

    # -- creation ----------------------------------------------------------------------------------------
    def validate(self, robot_id: str, body: CommandCreate) -> tuple[RobotState, dict[str, object]]:
        st = self._registry.get(robot_id)
        if st is None:
            raise CommandError(404, f"unknown robot {robot_id!r}")
        if not st.online:
            raise CommandError(409, f"robot {robot_id!r} is offline")
        if not self._publisher.connected:
            raise CommandError(503, "the server is not connected to the MQTT broker")
        if body.command not in st.capabilities.commands:
            supported = ", ".join(st.capabilities.commands) or "none"
            raise CommandError(
                422,
                f"command {body.command!r} is not supported by robot {robot_id!r} (supported: {supported})",
            )
        model = ARG_MODELS.get(body.command)
        if model is None:
            return st, dict(body.args)  # robot-specific command: the robot validates its own args
        try:
            return st, model.model_validate(body.args).model_dump()
        except ValidationError as exc:
            raise CommandError(422, f"bad args for {body.command!r}: {_format_errors(exc)}") from None

    async def create(self, robot_id: str, body: CommandCreate) -> CommandPublic:
        st, args = self.validate(robot_id, body)
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
        fut = self._writer.submit(repo.insert_command(row), want_result=True)
        if fut is not None:
            await asyncio.wrap_future(fut)  # stored before it is sent, so GET finds it at once
        if st.legacy:
            self._publisher.publish(LEGACY_COMMAND_TOPIC, cmd.command, qos=QOS_COMMAND)
            self._publisher.publish(legacy_namespaced_command_topic(robot_id), cmd.command, qos=QOS_COMMAND)
            self._hub.publish_control(
                {"type": "command", "command": public.model_dump(mode="json")}, robot_id
            )
            self._apply_ack(
                tracked, AckStatus.ACCEPTED, LEGACY_ACK_REASON, time.time(), time.time(), no_more=True
            )
        else:
            self._publisher.publish(self._topics.cmd(robot_id), dumps(cmd), qos=QOS_COMMAND)
            self._hub.publish_control(
                {"type": "command", "command": public.model_dump(mode="json")}, robot_id
            )
        return public.model_copy(deep=True)

    async def wait(self, command_id: str, timeout_s: float) -> tuple[CommandPublic, int]:
        tracked = self._cache.get(command_id)
        if tracked is None:
            raise CommandError(404, f"unknown command {command_id!r}")
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(tracked.final.wait(), timeout_s)
        cmd = tracked.cmd
        if tracked.final.is_set() or cmd.acks:
            return cmd.model_copy(deep=True), 200
        self._set_status(tracked, "timeout", f"no ack within {timeout_s:g} s")
        return cmd.model_copy(deep=True), 504

    # -- acks (event loop) -------------------------------------------------------------------------------
    def on_ack(self, robot_id: str, ack: Ack, received: float) -> bool:
        """Returns False when the ack's command is unknown here."""
        tracked = self._cache.get(ack.id)
        if tracked is None:
            # Not sent by this process (restart, another replica): record it if the database knows it.
            self.unknown_acks += 1
            ack_row = {"status": ack.status, "reason": ack.reason, "ts": ack.ts, "received_ts": received}
            fut = self._writer.submit(repo.apply_ack_if_known(ack.id, robot_id, ack_row), want_result=True)
            try:
                loop = asyncio.get_running_loop()
            except RuntimeError:  # called outside the server's loop (tests, tools): nobody to tell live
                loop = None
            if fut is not None and loop is not None:
                fut.add_done_callback(functools.partial(self._from_writer, loop))
            return False
        if tracked.cmd.robot_id != robot_id:
            raise ValueError(f"ack from {robot_id} for a command sent to {tracked.cmd.robot_id}")
        self._apply_ack(tracked, ack.status, ack.reason, ack.ts, received)
        return True

    def _from_writer(self, loop: asyncio.AbstractEventLoop, fut: concurrent.futures.Future[Any]) -> None:
        """Writer thread: a command sent by another replica (or before a restart) now has this ack; its
        WebSocket clients here see it too. Crosses to the event loop; never raises into the writer."""
        if fut.cancelled() or fut.exception() is not None:
            return
        cmd = fut.result()
        if cmd is not None and not loop.is_closed():
            loop.call_soon_threadsafe(self._known_elsewhere, cmd)

    def _known_elsewhere(self, cmd: CommandPublic) -> None:
        self._hub.publish_control({"type": "command", "command": cmd.model_dump(mode="json")}, cmd.robot_id)

    def _apply_ack(
        self, tracked: Tracked, status: str, reason: str, ts: float, received: float, no_more: bool = False
    ) -> None:
        cmd = tracked.cmd
        ack = AckPublic(status=status, reason=reason, ts=ts, received_ts=received)
        cmd.acks.append(ack)
        self.latency.observe(status, received - cmd.ts)
        if status in ("rejected", "expired"):
            log.warning("command %s %s to %s %s: %s", cmd.command, cmd.id, cmd.robot_id, status, reason,
                        extra={"robot_id": cmd.robot_id, "command_id": cmd.id, "reason": reason})
        # A late "accepted" never overrides a final status that already arrived.
        if not (tracked.final.is_set() and status not in FINAL_ACK_STATUSES):
            cmd.status = status  # type: ignore[assignment]
            cmd.reason = reason
        if status in FINAL_ACK_STATUSES or no_more:
            tracked.final.set()
        self._writer.submit(repo.update_command(cmd.id, cmd.status, cmd.reason, received, ack.model_dump()))
        self._hub.publish_control({"type": "command", "command": cmd.model_dump(mode="json")}, cmd.robot_id)

    def _set_status(self, tracked: Tracked, status: str, reason: str) -> None:
        cmd = tracked.cmd
        cmd.status = status  # type: ignore[assignment]
        cmd.reason = reason
        self._writer.submit(repo.update_command(cmd.id, status, reason, time.time()))
        self._hub.publish_control({"type": "command", "command": cmd.model_dump(mode="json")}, cmd.robot_id)

    def sweep(self, now: float) -> None:
        """Commands nobody acked within their ttl (plus grace) become "timeout"."""
        for tracked in self._cache.values():
            cmd = tracked.cmd
            if cmd.status == "sent" and not cmd.acks and now > cmd.ts + cmd.ttl_s + self._grace:
                self._set_status(tracked, "timeout", "no ack from robot")

    # -- reads ---------------------------------------------------------------------------------------------
    def cached(self, command_id: str) -> CommandPublic | None:
        tracked = self._cache.get(command_id)
        return tracked.cmd.model_copy(deep=True) if tracked else None

    def overlay(self, commands: list[CommandPublic]) -> list[CommandPublic]:
        """Prefer the in-memory record (it already has acks the writer may not have committed yet)."""
        return [self.cached(c.id) or c for c in commands]

    def _remember(self, tracked: Tracked) -> None:
        self._cache[tracked.cmd.id] = tracked
        while len(self._cache) > CACHE_MAX:
            self._cache.popitem(last=False)
