"""One operator in control: a robot's control lease.

Driving a robot (any command that can move it) needs its lease. The caller takes it explicitly or with its
first drive; it lapses ``lapse_s`` after the holder's last drive and is released on logout. Another caller
gets 409 ``lease_held`` naming the holder and the time of their last command; they can ask for control, and
the holder (or an admin, audited) hands it over. Stop, the e-stop and holds never need a lease.

The database is the arbiter between replicas: taking a lease is a conditional upsert (the writer thread
runs it). A holder's renewals are accepted from memory and confirmed in the database about once a second
in the background, so a drive never waits for the database once the lease is held, and an admin's takeover
on another replica reaches this one within that second (each replica also re-reads every lease once a
second, so a takeover or release elsewhere shows here even while nobody drives).

Goals (goto, paths) and missions *hold* the lease while they are under way: it is renewed for them, so it
never lapses mid-motion. A mission is a holder of its own ("mission <name> (started by alice)"); it takes
its robots' leases when it starts or resumes (all or none; the starter's own leases pass to it) and gives
them back when it pauses or ends, or when one of its robots drops out.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

from backend.core.errors import ServiceError
from backend.schemas import LeasePublic
from backend.services.access.audit import Actor, AuditService
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.store import leases as store
from backend.store.writer import BatchWriter

log = logging.getLogger(__name__)

LEASE_LAPSE_S = 60.0
#: a holder's renewals are re-confirmed in the database this often (an admin takeover elsewhere shows)
CONFIRM_EVERY_S = 1.0


#: a mission's lease holder id is this and the mission's id
MISSION_HOLDER = "mission:"
#: a mission's name in its lease holder's name (the column holds 160 characters)
MISSION_NAME_CHARS = 80


class LeaseHeld(ServiceError):
    def __init__(self, lease: LeasePublic, now: float) -> None:
        ago = max(0.0, now - lease.last_drive)
        what = (
            "pause or abort the mission to drive it"
            if lease.holder.startswith(MISSION_HOLDER)
            else "request control, or wait until the lease lapses"
        )
        super().__init__(
            409,
            f"robot {lease.robot_id!r} is driven by {lease.holder_name} (last command {ago:.1f} s ago); {what}",
            code="lease_held",
        )


@dataclass
class _Lease:
    public: LeasePublic
    confirmed_at: float


@dataclass(frozen=True)
class _Hold:
    """Something under way that holds a robot's lease for ``actor``: a goal (``command_id``, running while
    the command service says so) or a mission (``active``: while it still drives that robot)."""

    actor: Actor
    command_id: str | None = None
    active: Callable[[], bool] | None = None

    def under_way(self, running: Callable[[str], bool]) -> bool:
        if self.active is not None:
            return self.active()
        return self.command_id is not None and running(self.command_id)


class LeaseService:
    def __init__(
        self,
        *,
        writer: BatchWriter,
        hub: LiveHub,
        registry: Registry,
        audit: AuditService,
        lapse_s: float = LEASE_LAPSE_S,
    ) -> None:
        self._writer = writer
        self._hub = hub
        self._registry = registry
        self._audit = audit
        self.lapse_s = lapse_s
        self._leases: dict[str, _Lease] = {}
        #: robot -> the goal (goto, path) under way: its lease is renewed until it ends
        self._goals: dict[str, _Hold] = {}
        #: robot -> the mission driving it: its lease is renewed while the mission runs, released after
        self._missions: dict[str, _Hold] = {}
        #: robot -> how often its cached lease changed (a database read older than a change is not applied)
        self._version: dict[str, int] = {}
        self._synced_at = 0.0

    def current(self, robot_id: str, now: float | None = None) -> LeasePublic | None:
        lease = self._leases.get(robot_id)
        now = time.time() if now is None else now
        if lease is None or now - lease.public.last_drive > self.lapse_s:
            return None
        return lease.public

    async def drive(self, robot_id: str, actor: Actor, via: str = "drive") -> LeasePublic:
        """A drive by ``actor``: renew its lease, or take a free one; 409 when someone else holds it."""
        now = time.time()
        lease = self._leases.get(robot_id)
        if lease is not None and now - lease.public.last_drive <= self.lapse_s:
            if lease.public.holder != actor.lease_holder:
                raise LeaseHeld(lease.public, now)
            lease.public.last_drive = now
            if now - lease.confirmed_at >= CONFIRM_EVERY_S:
                lease.confirmed_at = now
                self._confirm_later(robot_id, actor, via, now)
            return lease.public
        return (await self._acquire(robot_id, actor, via, now, force=False))[0]

    async def take(self, robot_id: str, actor: Actor, force: bool) -> LeasePublic:
        """ "Take control" (``force``: an admin's takeover, audited)."""
        now = time.time()
        lease = self.current(robot_id, now)
        if lease is not None and lease.holder != actor.lease_holder and not force:
            raise LeaseHeld(lease, now)
        result, before = await self._acquire(robot_id, actor, "take", now, force=force)
        if force and before is not None and before.holder != actor.lease_holder:  # as the database had it
            self._audit.record(actor, "lease_takeover", robot_id, {"from": before.holder_name})
        return result

    async def _acquire(
        self, robot_id: str, actor: Actor, via: str, now: float, force: bool
    ) -> tuple[LeasePublic, LeasePublic | None]:
        """Take or renew in the database; returns the lease and the live lease it replaced (None: it was free)."""
        op = store.acquire_lease(robot_id, actor.lease_holder, actor.name, now, self.lapse_s, via, force)
        fut = self._writer.submit(op, want_result=True, after_rows=False, retry=False)
        assert fut is not None
        before_row, row = await asyncio.wrap_future(fut)
        public = LeasePublic(**row)
        self._keep(robot_id, _Lease(public, now))
        if public.holder != actor.lease_holder:
            raise LeaseHeld(public, now)
        before = self._live(before_row, now)
        if before is None or before.holder != public.holder:
            self._audit.record(actor, "lease_take", robot_id, {"via": via})
            self._changed(robot_id)
        return public, before

    def _live(self, row: dict[str, Any] | None, now: float) -> LeasePublic | None:
        return LeasePublic(**row) if row is not None and now - row["last_drive"] <= self.lapse_s else None

    def _confirm_later(self, robot_id: str, actor: Actor, via: str, now: float) -> None:
        """Refresh the row in the database (last_drive) and learn of a takeover on another replica."""
        op = store.acquire_lease(robot_id, actor.lease_holder, actor.name, now, self.lapse_s, via, False)
        fut = self._writer.submit(op, want_result=True, after_rows=False, retry=False)
        if fut is None:
            return
        loop = asyncio.get_running_loop()

        def done(f: Any) -> None:
            if f.cancelled() or f.exception() is not None:
                return
            _, row = f.result()
            loop.call_soon_threadsafe(self._confirmed, robot_id, LeasePublic(**row))

        fut.add_done_callback(done)

    def _confirmed(self, robot_id: str, public: LeasePublic) -> None:
        lease = self._leases.get(robot_id)
        if lease is not None and lease.public.holder != public.holder:
            log.warning("lease of %s is now %s's (taken over elsewhere)", robot_id, public.holder_name)
            self._keep(robot_id, _Lease(public, time.time()))
            self._changed(robot_id)

    async def release(self, robot_id: str, actor: Actor, anyone: bool = False) -> bool:
        fut = self._writer.submit(
            store.release_lease(robot_id, None if anyone else actor.lease_holder),
            want_result=True,
            after_rows=False,
            retry=False,
        )
        assert fut is not None
        released = bool(await asyncio.wrap_future(fut))
        lease = self._leases.get(robot_id)
        if lease is not None and (anyone or lease.public.holder == actor.lease_holder):
            self._keep(robot_id, None)
            released = True
        if released:
            self._audit.record(actor, "lease_release", robot_id, {})
            self._changed(robot_id)
        return released

    async def grant(self, robot_id: str, actor: Actor, to: Actor) -> LeasePublic:
        """The holder hands the lease to ``to`` (who asked for control)."""
        now = time.time()
        lease = self.current(robot_id, now)
        if lease is None or lease.holder != actor.lease_holder:
            raise ServiceError(409, f"you do not hold the lease of {robot_id!r}", code="lease_not_yours")
        result, _ = await self._acquire(robot_id, to, "grant", now, force=True)
        self._audit.record(actor, "lease_grant", robot_id, {"to": to.name, "to_holder": to.lease_holder})
        return result

    def request(self, robot_id: str, actor: Actor) -> LeasePublic:
        """Ask the holder for control: every client sees the request; the holder's can grant it."""
        lease = self.current(robot_id)
        if lease is None:
            raise ServiceError(409, f"nobody holds {robot_id!r}: take control instead", code="lease_free")
        self._audit.record(actor, "lease_request", robot_id, {"holder": lease.holder_name})
        self._hub.publish_control(
            {
                "type": "lease_request",
                "robot_id": robot_id,
                "from": actor.name,
                "from_holder": actor.lease_holder,
                "holder": lease.holder,
                "ts": time.time(),
            },
            robot_id,
        )
        return lease

    def hold_for_goal(self, robot_id: str, actor: Actor, command_id: str) -> None:
        """A goal (goto, path) by ``actor`` is under way: its lease must not lapse mid-motion, however long the
        goal takes without a drive command (:meth:`renew_goals` keeps it)."""
        self._goals[robot_id] = _Hold(actor, command_id=command_id)

    async def renew_goals(self, now: float, running: Callable[[str], bool]) -> None:
        """Renew the lease of every goal still ``running`` (by command id) and of every mission still driving
        its robot, well before it would lapse; a goal that ended, or whose lease someone else now holds (an
        admin took over), is let go. A mission's lease is released once it no longer drives the robot."""
        for held, is_mission in ((self._goals, False), (self._missions, True)):
            for robot_id, hold in list(held.items()):
                lease = self._leases.get(robot_id)
                st = self._registry.get(robot_id)
                gone = st is None or not st.online  # its goal ended with the link (the robot fails it itself)
                ours = lease is not None and lease.public.holder == hold.actor.lease_holder
                if (gone and not is_mission) or not hold.under_way(running) or not ours:
                    held.pop(robot_id, None)
                    if is_mission and ours:
                        await self.release(robot_id, hold.actor)
                elif lease is not None and now - lease.public.last_drive >= self.lapse_s / 3:
                    try:
                        await self.drive(robot_id, hold.actor, via="mission" if is_mission else "goal")
                    except LeaseHeld:
                        held.pop(robot_id, None)

    # -- missions -------------------------------------------------------------------------------------------
    @staticmethod
    def mission_actor(mission_id: str, name: str, by: Actor, verb: str = "started") -> Actor:
        """The holder a mission drives as: its own (``mission:<id>``), named for the people who see a 409 or
        the "driven by" label; the audit trail keeps the operator's subject, token and address."""
        return replace(
            by,
            name=f"mission {name[:MISSION_NAME_CHARS]} ({verb} by {by.name})"[:160],
            holder=f"{MISSION_HOLDER}{mission_id}",
        )

    async def take_for_mission(
        self, robot_ids: list[str], mission: Actor, by: Actor, driving: Callable[[str], bool]
    ) -> None:
        """A mission starts or resumes: it takes the lease of each robot, all or none. The operator's own
        leases pass to it; a robot someone else drives refuses the lot with 409 naming them. The leases are
        then renewed while ``driving(robot)`` says the mission still drives that robot."""
        now = time.time()
        op = store.acquire_leases(
            robot_ids, mission.lease_holder, mission.name, now, self.lapse_s, "mission", by.lease_holder
        )
        fut = self._writer.submit(op, want_result=True, after_rows=False, retry=False)
        assert fut is not None
        try:
            taken, refused = await asyncio.wrap_future(fut)
        except store.LeaseConflict:
            raise ServiceError(
                409, "another operator took one of the robots meanwhile; try again", code="lease_held"
            ) from None
        if refused is not None:
            public = LeasePublic(**refused)
            self._keep(public.robot_id, _Lease(public, now))
            raise LeaseHeld(public, now)
        for before_row, row in taken:
            public = LeasePublic(**row)
            rid = public.robot_id
            self._keep(rid, _Lease(public, now))
            self._missions[rid] = _Hold(mission, active=partial(driving, rid))
            before = self._live(before_row, now)
            if before is None or before.holder != public.holder:
                detail = {"via": "mission"} | ({"from": before.holder_name} if before is not None else {})
                self._audit.record(mission, "lease_take", rid, detail)
                self._changed(rid)

    async def release_mission(self, mission: Actor) -> list[str]:
        """The mission paused or ended: every lease it holds goes (audited), at once."""
        robots = [rid for rid, hold in self._missions.items() if hold.actor.lease_holder == mission.lease_holder]
        for rid in robots:
            self._missions.pop(rid, None)
            lease = self._leases.get(rid)
            if lease is not None and lease.public.holder == mission.lease_holder:
                await self.release(rid, mission)
        return robots

    def forget_mission(self, mission_id: str, why: str) -> None:
        """A mission paused by a restart holds nothing: the leases its dead process left in the database go
        (audited once, by ``system``), instead of keeping its robots from everyone until they lapse."""
        holder = f"{MISSION_HOLDER}{mission_id}"
        fut = self._writer.submit(store.release_leases_of(holder), want_result=True, after_rows=False, retry=False)
        if fut is None:
            return
        loop = asyncio.get_running_loop()
        system = Actor(subject="system", name="system")

        def done(f: Any) -> None:
            if not f.cancelled() and f.exception() is None:
                for rid in f.result():
                    loop.call_soon_threadsafe(self._audit.record, system, "lease_release", rid, {"why": why})

        fut.add_done_callback(done)

    # -- replicas -------------------------------------------------------------------------------------------
    def sync(self, now: float) -> None:
        """About once a second: re-read every lease, so that a takeover, release or lease taken on another
        replica shows here (``GET`` lease, "driven by", the next drive's 409) even while nobody drives."""
        if now - self._synced_at < CONFIRM_EVERY_S:
            return
        self._synced_at = now
        versions = dict(self._version)
        self._writer.read_then(store.load_leases(), lambda rows: self._synced(rows, versions))

    def _synced(self, rows: list[dict[str, Any]], versions: dict[str, int]) -> None:
        now = time.time()
        found = {row["robot_id"]: row for row in rows}
        for rid in set(found) | set(self._leases):
            if self._version.get(rid, 0) != versions.get(rid, 0):
                continue  # changed here since the read was queued: this replica's view is newer
            mine, row = self._leases.get(rid), found.get(rid)
            if mine is not None and row is not None and mine.public.holder == row["holder"]:
                # the same holder: whichever renewal is newer (this replica's, or one through another replica;
                # this replica's own reach the row up to a second late)
                mine.public.last_drive = max(mine.public.last_drive, row["last_drive"])
                continue
            theirs = self._live(row, now)
            if theirs is None and (mine is None or now - mine.public.last_drive > self.lapse_s):
                continue
            log.info(
                "lease of %s: %s here, %s in the database",
                rid,
                mine and mine.public.holder_name,
                theirs and theirs.holder_name,
            )
            self._keep(rid, _Lease(theirs, now) if theirs is not None else None)
            self._changed(rid)

    async def release_all_of(self, actor: Actor, why: str = "logout") -> list[str]:
        """Logout (or a revoked, disabled or demoted holder, ``why``): every lease of this holder goes."""
        fut = self._writer.submit(
            store.release_leases_of(actor.lease_holder), want_result=True, after_rows=False, retry=False
        )
        assert fut is not None
        robots: list[str] = await asyncio.wrap_future(fut)
        for rid in [r for r, lease in self._leases.items() if lease.public.holder == actor.lease_holder]:
            self._keep(rid, None)
            if rid not in robots:
                robots.append(rid)
        for rid in robots:
            self._audit.record(actor, "lease_release", rid, {"why": why})
            self._changed(rid)
        return robots

    def _keep(self, robot_id: str, lease: _Lease | None) -> None:
        """The one place the cache changes; the robot's state shows the same record (``GET /api/robots``)."""
        self._version[robot_id] = self._version.get(robot_id, 0) + 1
        if lease is None:
            self._leases.pop(robot_id, None)
        else:
            self._leases[robot_id] = lease
        st = self._registry.get(robot_id)
        if st is not None:
            st.lease = lease.public if lease is not None else None

    def _changed(self, robot_id: str) -> None:
        st = self._registry.get(robot_id)
        lease = self.current(robot_id)
        self._hub.publish_control(
            {"type": "lease", "robot_id": robot_id, "lease": lease.model_dump(mode="json") if lease else None},
            robot_id,
        )
        if st is not None:
            self._registry.push(st)
