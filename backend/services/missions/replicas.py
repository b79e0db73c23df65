"""Which replica runs a mission: the row lease it renews, the pause or abort asked through another replica,
and the takeover (paused) of the missions of a replica gone silent. docs/missions.md, "Replicas"."""

from __future__ import annotations

import asyncio
import time
from typing import Any

from backend.core.errors import ServiceError
from backend.schemas.missions import MissionPublic
from backend.services.missions.book import ENDED, SYSTEM, MissionBook, log, mission_from_row, pause_robots
from backend.services.missions.record import Mission, mission_public
from backend.store import missions as store

#: a replica renews its running missions' row lease this often, and looks for orphans and changes as often
RENEW_S = 1.0
#: a running mission whose owner has not renewed for this long may be taken over (paused) by another replica
LEASE_S = 3.0
#: a mirror re-reads rows changed this long before its last look (writes commit late on a loaded server)
MIRROR_MARGIN_S = 10.0
#: a pause or abort asked through a replica that does not run the mission: how long it waits for the owner
ASK_WAIT_S = 2.5


class ReplicaOwnership(MissionBook):
    async def _ask(self, m: Mission, action: str, actor: str, reason: str) -> bool:
        """A pause or abort of a mission that another live replica runs: recorded in its row for that replica
        to apply (it reads it with its lease renewal, every second). True when asked; False when this replica
        may act itself. Safety does not wait for this: if the owner is dead its robots have stopped already
        (supervision), and the takeover pauses the mission."""
        now = self._clock()
        row = await asyncio.to_thread(store.load_one, self._engine, m.id)
        if row is None or row["state"] != "running" or row["owner"] in (None, self.server_id):
            return False
        if row["heartbeat_at"] is None or row["heartbeat_at"] < now - LEASE_S:
            return False  # its owner is gone: this replica takes it (the compare-and-set of _claim)
        by = f"{'paused' if action == 'pause' else 'aborted'} by an operator through replica {self.server_id}"
        asked = {"action": action, "actor": actor, "reason": reason or by, "by": self.server_id, "ts": now}
        if not await self._write(store.request(m.id, row["owner"], asked)):
            return False  # it stopped running meanwhile: act here (or refuse by its new state)
        log.info("mission %s: %s asked of replica %s", m.id, action, row["owner"])
        m.requested = asked
        return True

    async def _await_owner(self, mission_id: str, states: tuple[str, ...]) -> tuple[MissionPublic, bool]:
        """Wait (up to ``ASK_WAIT_S``) for the owner to apply an asked action: its transition stored (the row's
        state changes a moment before, with the claim); the mission as the row then has it."""
        asked_at = self._clock()
        deadline = time.monotonic() + ASK_WAIT_S
        while True:
            row = await asyncio.to_thread(store.load_one, self._engine, mission_id)
            if row is not None and row["state"] in states:
                transitions, _ = await asyncio.to_thread(store.history, self._engine, mission_id, 1)
                last = transitions[-1] if transitions else {}
                if last.get("to_state") == row["state"] and last.get("ts", 0.0) >= asked_at - 1.0:
                    row = await asyncio.to_thread(store.load_one, self._engine, mission_id)
                    if row is not None:
                        async with self._lock:
                            self.missions[mission_id] = m = mission_from_row(row)
                            self._push(m)
                        return mission_public(m), True
            if time.monotonic() >= deadline:
                return mission_public(self.get(mission_id)), False
            await asyncio.sleep(0.1)

    async def _replicas(self, now: float) -> None:
        """The row lease: renew this replica's running missions (and let go of any another replica took over
        while this one was silent), pause the running missions of a replica gone silent (taken over), and
        mirror what other replicas changed."""
        mine = [m.id for m in self.missions.values() if m.state == "running" and m.owner == self.server_id]
        if mine:
            renewed: dict[str, dict[str, Any] | None] = await self._write(store.renew(self.server_id, mine, now))
            kept = set(renewed)
            for mid, asked in renewed.items():
                if asked:
                    await self._apply_asked(self.missions[mid], asked)
            for mid in set(mine) - kept:
                log.warning("mission %s: taken over by another replica while this one was silent: let go", mid)
                self._end_formation(mid)  # its fast loop drives nothing more from here
                row = await asyncio.to_thread(store.load_one, self._engine, mid)
                if row is not None:
                    self.missions[mid] = mission_from_row(row)
                    self._push(self.missions[mid])
        self._renewed_at = now
        for orphan in await asyncio.to_thread(store.orphaned, self._engine, self.server_id, now, LEASE_S):
            await self._take_over(orphan, now)
        since, self._synced_at = self._synced_at, now
        for row in await asyncio.to_thread(store.load_changed, self._engine, since - MIRROR_MARGIN_S, self.server_id):
            m = self.missions.get(row["id"])
            ours = m is not None and m.owner == self.server_id and m.state == "running"
            if not ours and (m is None or row["updated_at"] > m.updated_at):
                self.missions[row["id"]] = mirrored(m, row)
                self._push(self.missions[row["id"]])

    async def _apply_asked(self, m: Mission, asked: dict[str, Any]) -> None:
        """A pause or abort asked through another replica: applied here, by the one that runs the mission, as
        if asked here (the actor is the operator who asked; the claim clears the request)."""
        state = "aborted" if asked.get("action") == "abort" else "paused"
        if m.state != "running":
            return
        try:
            await self._claim(m, state, self._clock())
        except ServiceError as exc:
            log.warning("mission %s: could not apply %s asked through %s: %s", m.id, state, asked.get("by"), exc)
            return
        await self._halt(m, state, str(asked.get("actor") or SYSTEM), str(asked.get("reason") or ""))

    async def _take_over(self, orphan: dict[str, Any], now: float) -> None:
        """A running mission whose replica went silent (its robots stopped with its heartbeat): this replica
        takes it, paused with the reason; an operator resumes it."""
        previous = orphan["owner"] or "an unknown replica"
        reason = f"replica {previous} went silent: taken over by {self.server_id}; the robots stopped"
        transition = {
            "mission_id": orphan["id"],
            "ts": now,
            "from_state": "running",
            "to_state": "paused",
            "actor": SYSTEM,
            "reason": reason,
        }
        values = {"state": "paused", "reason": reason, "updated_at": now}
        claim = store.claim(orphan["id"], self.server_id, now, LEASE_S, ("running",), values, transition)
        if not await self._write(claim):
            return  # another replica was first
        row = await asyncio.to_thread(store.load_one, self._engine, orphan["id"])
        if row is None:
            return
        m = mission_from_row(row)
        m.running_since = None
        pause_robots(m)
        self.missions[m.id] = m
        log.warning("mission %s: %s", m.id, reason)
        self._event(m, "takeover", None, {"from": orphan["owner"], "to": self.server_id}, now)
        self._save(m, now)

    async def _claim_or_release(self, m: Mission, now: float) -> None:
        """Start or resume: claim the mission for this replica; if another replica has it, the leases just
        taken for it are given back (nothing else changed)."""
        try:
            await self._claim(m, "running", now)
        except ServiceError:
            await self._release_leases(m)
            raise

    async def _claim(self, m: Mission, state: str, now: float) -> None:
        """Make the mission this replica's, moving it to ``state`` in the same statement (compare and set:
        the row must still be in the state this replica saw, and no live replica may be running it)."""
        values = {"state": state, "updated_at": now, "requested": None}
        op = store.claim(m.id, self.server_id, now, LEASE_S, (m.state,), values)
        if await self._write(op):
            m.owner, m.requested = self.server_id, None
            return
        row = await asyncio.to_thread(store.load_one, self._engine, m.id)
        if row is not None:
            self.missions[m.id] = mission_from_row(row)
        fresh = self.missions[m.id]
        if fresh.state == "running" and fresh.owner not in (None, self.server_id):
            raise ServiceError(
                409,
                f"mission {m.id} runs on replica {fresh.owner}: act on it there (the fleet e-stop works everywhere)",
                "mission_on_other_replica",
            )
        raise ServiceError(409, f"the mission is {fresh.state} now (changed on another replica)", "bad_mission_state")


def mirrored(old: Mission | None, row: dict[str, Any]) -> Mission:
    """Another replica's newer row of a mission. Its coverage is the figures that replica stored, no geometry
    (book.mission_from_row: a row is read on the event loop, one per change); but when this replica has its
    grid already (its coverage was asked here), the grid goes on with the points the row adds to the same
    plan's tracks, as a step's update does (bounded), instead of being built again from the whole tracks."""
    m = mission_from_row(row)
    if old is None or old.coverage.grid is None or (old.plan, old.params) != (m.plan, m.params) or m.state in ENDED:
        return m
    if old.coverage.continues(m.robots):
        m.coverage = old.coverage
        m.coverage.update(m.robots)
    return m
