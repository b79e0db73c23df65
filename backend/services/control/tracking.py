"""A command's life after it is sent: the in-memory record of each (its public shape, whether a final ack
came, the ``?wait`` requests waiting for one), the acks applied to it (also for commands another replica
sent), the timeouts, and the reads that merge it with the database."""

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

from backend.core.metrics import Histogram
from backend.schemas import AckPublic, CommandPublic
from backend.services.control.args import CommandError
from backend.services.live.hub import LiveHub
from backend.store import repository as repo
from backend.store.writer import BatchWriter
from fleet_protocol import FINAL_ACK_STATUSES, Ack

log = logging.getLogger(__name__)

CACHE_MAX = 5000
#: an ack for a command not in the database is tried again after these delays (the sending replica
#: publishes a command before its row is committed, so its ack can overtake the commit)
UNKNOWN_ACK_RETRY_S = (0.2, 1.0, 5.0)
#: at most this many such acks wait for a retry at a time (a robot sending acks for made-up ids must not
#: turn each into four database lookups without bound); beyond it an unknown ack is looked up once
MAX_PENDING_ACK_RETRIES = 500


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
            wake(waiter)
        self.waiters.clear()


def wake(waiter: asyncio.Future[None]) -> None:
    """Resume a ``?wait`` request (final ack or its timeout, whichever comes first)."""
    if not waiter.done():
        waiter.set_result(None)


class CommandTracking:
    """The commands this server sent, kept in memory (the newest ``CACHE_MAX``) with their acks."""

    def __init__(self, *, writer: BatchWriter, hub: LiveHub, ack_timeout_grace_s: float) -> None:
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

    async def wait(self, command_id: str, timeout_s: float) -> tuple[CommandPublic, int]:
        tracked = self._cache.get(command_id)
        if tracked is None:
            raise CommandError(404, f"unknown command {command_id!r}", "unknown_command")
        if not tracked.final:
            loop = asyncio.get_running_loop()
            waiter: asyncio.Future[None] = loop.create_future()
            tracked.waiters.append(waiter)
            timer = loop.call_later(timeout_s, wake, waiter)
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
            fut.add_done_callback(functools.partial(self._from_writer, loop, (command_id, robot_id, ack_row, attempt)))
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
                    log.warning(
                        "%d acks for unknown commands not retried (%d already waiting); latest from %s",
                        self.ack_retries_refused,
                        MAX_PENDING_ACK_RETRIES,
                        robot_id[:64],
                    )
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
            log.warning(
                "command %s %s to %s %s: %s",
                cmd.command,
                cmd.id,
                cmd.robot_id,
                status,
                reason,
                extra={"robot_id": cmd.robot_id, "command_id": cmd.id, "reason": reason},
            )
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
    def running(self, command_id: str) -> bool:
        """Whether the command is known here and has no final ack yet (a goal still under way)."""
        tracked = self._cache.get(command_id)
        return tracked is not None and tracked.cmd.status not in FINAL_ACK_STATUSES | {"timeout"}

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
