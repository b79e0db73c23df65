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
    Command,
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
#: an ack for a command not in the database is tried again after these delays (the sending replica
#: publishes a command before its row is committed, so its ack can overtake the commit)
UNKNOWN_ACK_RETRY_S = (0.2, 1.0, 5.0)
#: at most this many such acks wait for a retry at a time (a robot sending acks for made-up ids must not
#: turn each into four database lookups without bound); beyond it an unknown ack is looked up once
MAX_PENDING_ACK_RETRIES = 500


class CommandError(Exception):
    def __init__(self, status_code: int, detail: str) -> None:
        super().__init__(detail)
        self.status_code = status_code
        self.detail = detail


@dataclass
class Tracked:
    cmd: CommandPublic
    #: a final ack (done, rejected, expired...) arrived
    final: bool = False
    #: ``?wait`` requests: plain futures resolved by the ack itself, so the request resumes on the next
    #: loop turn (``wait_for`` on an ``Event`` took three turns, each behind the fleet's telemetry)
    waiters: list[asyncio.Future[None]] = field(default_factory=list)

    def finish(self) -> None:
        self.final = True
        for waiter in self.waiters:
            _wake(waiter)
        self.waiters.clear()


def _wake(waiter: asyncio.Future[None]) -> None:
    """Resume a ``?wait`` request (final ack or its timeout, whichever comes first)."""
    if not waiter.done():
        waiter.set_result(None)


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
        self._ack_retries_pending = 0
        #: unknown acks not retried because MAX_PENDING_ACK_RETRIES were already waiting
        self.ack_retries_refused = 0
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
        # Published without waiting for its row: the commit queues behind telemetry batches and the
        # rollup's transactions, and waiting for it was most of the round trip's p99 under load. Nothing is
        # lost by not waiting: an ack that overtakes the commit finds the command in this cache and its
        # update queues behind the insert (one FIFO writer); another replica retries it until the row is
        # there (see _from_writer); reads merge this cache in (cached(), overlay()).
        self._send(st, robot_id, cmd, public, tracked)
        self._writer.submit(repo.insert_command(row), after_rows=False)
        return public.model_copy(deep=True)

    def _send(
        self, st: RobotState, robot_id: str, cmd: Command, public: CommandPublic, tracked: Tracked
    ) -> None:
        """Publish the command (legacy robots: the plain string, acked "accepted" here) and tell live clients."""
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

    async def wait(self, command_id: str, timeout_s: float) -> tuple[CommandPublic, int]:
        tracked = self._cache.get(command_id)
        if tracked is None:
            raise CommandError(404, f"unknown command {command_id!r}")
        if not tracked.final:
            loop = asyncio.get_running_loop()
            waiter: asyncio.Future[None] = loop.create_future()
            tracked.waiters.append(waiter)
            timer = loop.call_later(timeout_s, _wake, waiter)
            try:
                await waiter
            finally:
                timer.cancel()
                with contextlib.suppress(ValueError):
                    tracked.waiters.remove(waiter)
        cmd = tracked.cmd
        if tracked.final or cmd.acks:
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
            try:
                loop = asyncio.get_running_loop()
            except RuntimeError:  # called outside the server's loop (tests, tools): nobody to tell live
                loop = None
            self._apply_unknown_ack(loop, ack.id, robot_id, ack_row, 0)
            return False
        if tracked.cmd.robot_id != robot_id:
            raise ValueError(f"ack from {robot_id} for a command sent to {tracked.cmd.robot_id}")
        self._apply_ack(tracked, ack.status, ack.reason, ack.ts, received)
        return True

    def _apply_unknown_ack(
        self,
        loop: asyncio.AbstractEventLoop | None,
        command_id: str,
        robot_id: str,
        ack_row: dict[str, Any],
        attempt: int,
    ) -> None:
        """Event loop: record the ack if the database knows its command (attempt 0, then retries)."""
        fut = self._writer.submit(repo.apply_ack_if_known(command_id, robot_id, ack_row), want_result=True)
        if fut is not None and loop is not None:
            fut.add_done_callback(
                functools.partial(self._from_writer, loop, (command_id, robot_id, ack_row, attempt))
            )
        elif attempt > 0:
            self._retry_finished()

    def _from_writer(
        self,
        loop: asyncio.AbstractEventLoop,
        retry: tuple[str, str, dict[str, Any], int],
        fut: concurrent.futures.Future[Any],
    ) -> None:
        """Writer thread: a command sent by another replica (or before a restart) now has this ack; its
        WebSocket clients here see it too. A command not in the database yet may just not be committed:
        the sending replica publishes it before its commit, so the ack is tried again a few times.
        Crosses to the event loop; never raises into the writer."""
        command_id, robot_id, ack_row, attempt = retry
        failed = fut.cancelled() or fut.exception() is not None
        cmd = None if failed else fut.result()
        with contextlib.suppress(RuntimeError):  # the loop is closed (shutdown)
            if cmd is not None:
                loop.call_soon_threadsafe(self._known_elsewhere, cmd)
            if not failed and cmd is None and attempt < len(UNKNOWN_ACK_RETRY_S):
                loop.call_soon_threadsafe(self._schedule_retry, loop, command_id, robot_id, ack_row, attempt)
            elif attempt > 0:
                loop.call_soon_threadsafe(self._retry_finished)

    def _schedule_retry(
        self, loop: asyncio.AbstractEventLoop, command_id: str, robot_id: str, ack_row: dict[str, Any], attempt: int
    ) -> None:
        """Event loop: look the ack's command up again later, within the bound on acks waiting for it."""
        if attempt == 0:
            if self._ack_retries_pending >= MAX_PENDING_ACK_RETRIES:
                self.ack_retries_refused += 1
                if self.ack_retries_refused % 100 == 1:
                    log.warning("%d acks for unknown commands not retried (%d already waiting); latest from %s",
                                self.ack_retries_refused, MAX_PENDING_ACK_RETRIES, robot_id[:64])
                return
            self._ack_retries_pending += 1
        loop.call_later(
            UNKNOWN_ACK_RETRY_S[attempt], self._apply_unknown_ack, loop, command_id, robot_id, ack_row, attempt + 1
        )

    def _retry_finished(self) -> None:
        self._ack_retries_pending -= 1

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
        if not (tracked.final and status not in FINAL_ACK_STATUSES):
            cmd.status = status  # type: ignore[assignment]
            cmd.reason = reason
        if status in FINAL_ACK_STATUSES or no_more:
            tracked.finish()
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

    def overlay(
        self,
        commands: list[CommandPublic],
        robot_id: str,
        start: float | None = None,
        end: float | None = None,
        limit: int = 100,
    ) -> list[CommandPublic]:
        """A database page of ``robot_id``'s commands (newest first) with the in-memory records: those
        have acks the writer may not have committed yet, and commands whose row is not committed yet
        (a POST returns before the commit) join the page where their time puts them."""
        page = {c.id: self.cached(c.id) or c for c in commands}
        for tracked in reversed(self._cache.values()):  # newest first
            cmd = tracked.cmd
            if cmd.robot_id != robot_id or cmd.id in page:
                continue
            if (start is not None and cmd.ts < start) or (end is not None and cmd.ts > end):
                continue
            page[cmd.id] = cmd.model_copy(deep=True)
        return sorted(page.values(), key=lambda c: c.ts, reverse=True)[:limit]

    def _remember(self, tracked: Tracked) -> None:
        self._cache[tracked.cmd.id] = tracked
        while len(self._cache) > CACHE_MAX:
            self._cache.popitem(last=False)
