"""Missions: create (plan), start, pause, resume, abort; run them (send legs, watch acks, positions and
dropouts); store every transition; survive a restart as ``paused``. docs/missions.md explains the design."""

from __future__ import annotations

import asyncio
import logging
import math
import time
import uuid
from functools import partial
from typing import Any

from sqlalchemy import Engine

from backend.core.alarm_rules import OFFLINE_IN_MISSION
from backend.core.errors import ServiceError
from backend.schemas.commands import CommandCreate
from backend.schemas.missions import (
    CoverageMissionCreate,
    FormationMissionCreate,
    MissionPublic,
    WaypointsMissionCreate,
)
from backend.schemas.runs import RunCreate
from backend.services.access.audit import Actor
from backend.services.control.args import CommandError
from backend.services.control.commands import CommandService
from backend.services.control.leases import LeaseService
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.services.missions.formation import DRIVE_DEADMAN_S, FormationDriver
from backend.services.missions.record import (
    Mission,
    coverage_of,
    mission_public,
    mission_row,
    plan_coverage_mission,
    plan_formation_mission,
    plan_waypoints_mission,
)
from backend.services.missions.site_source import SiteSource
from backend.services.missions.state import HOLD_DRIFT_M, HOLD_TOLERANCE_M, RobotRun, replan
from backend.services.runs.recorder import RunService
from backend.services.safety.alarms import AlarmService
from backend.services.safety.estop import EStopService
from backend.store import missions as store
from backend.store.writer import BatchWriter

log = logging.getLogger(__name__)

TICK_S = 0.2
SAVE_EVERY_S = 2.0
LEG_TOLERANCE_M = 0.08
FAILED_COMMAND = ("failed", "aborted", "rejected", "expired", "timeout")
ENDED = ("completed", "aborted", "failed")
SYSTEM = "system"
MAX_RETRIES = 3
#: a replica renews its running missions' row lease this often, and looks for orphans and changes as often
RENEW_S = 1.0
#: a running mission whose owner has not renewed for this long may be taken over (paused) by another replica
LEASE_S = 3.0
#: a mirror re-reads rows changed this long before its last look (writes commit late on a loaded server)
MIRROR_MARGIN_S = 10.0
#: a robot outside the mission closer than the minimum separation + this to one of its robots: a warning event
NEAR_MARGIN_M = 0.2
#: ... warned about again once it went this much further away first
NEAR_REARM_M = 0.1
#: positions older than this are not compared
NEAR_FIX_S = 2.0
#: a pause or abort asked through a replica that does not run the mission: how long it waits for the owner
ASK_WAIT_S = 2.5


class MissionService:
    def __init__(
        self,
        *,
        writer: BatchWriter,
        hub: LiveHub,
        registry: Registry,
        commands: CommandService,
        estop: EStopService,
        site: SiteSource,
        alarms: AlarmService,
        engine: Engine,
        server_id: str,
        leases: LeaseService,
        runs: RunService,
    ) -> None:
        self._runs = runs
        #: runs being closed (a mission that ended stops the run it opened)
        self._closing: set[asyncio.Task[None]] = set()
        self._engine = engine
        #: this replica's id (its heartbeat's server_id): it owns the missions it runs, and their legs name it
        self.server_id = server_id
        self._renewed_at = 0.0
        self._synced_at = time.time()
        self._leases = leases
        #: mission id -> the lease holder it drives its robots as, while it runs
        self._drivers: dict[str, Actor] = {}
        self._writer = writer
        self._hub = hub
        self._registry = registry
        self._commands = commands
        self._estop = estop
        self._site = site
        self._alarms = alarms
        self.missions: dict[str, Mission] = {}
        self._lock = asyncio.Lock()
        #: the fast loops of running formation missions (mission id -> its driver)
        self._formations: dict[str, FormationDriver] = {}

    # -- loading --------------------------------------------------------------------------------------
    def load(self, rows: list[dict[str, Any]]) -> None:
        """A mission that this replica was running when it stopped is paused, with the reason: the robots
        stopped when its heartbeat did (supervision), and an operator decides when it carries on. One that
        another replica runs is mirrored (the takeover of a silent replica's missions: :meth:`_replicas`)."""
        now = time.time()
        for row in rows:
            m = _from_row(row)
            self.missions[m.id] = m
            if m.state == "running" and m.owner in (None, self.server_id):
                m.owner, m.running_since = self.server_id, None  # the time it was down is not running time
                _pause_robots(m)
                self._transition(m, "paused", SYSTEM, "server restarted: the robots stopped without supervision", now)
                self._leases.forget_mission(m.id, "server restarted")

    # -- creating -------------------------------------------------------------------------------------
    def create(
        self, body: CoverageMissionCreate | WaypointsMissionCreate | FormationMissionCreate, created_by: str
    ) -> MissionPublic:
        unknown = [r for r in body.robots if self._registry.get(r) is None]
        if unknown:
            # 422 naming the field: the body names robots the server has never seen (a 404 would say the
            # mission route itself is missing); schemathesis is told so in tests/backend/api/schemathesis.toml
            raise ServiceError(422, f"robots: unknown robots: {', '.join(unknown)}", "unknown_robot")
        if isinstance(body, CoverageMissionCreate):
            plan, robots = plan_coverage_mission(
                self._site.current(), body.params.model_dump(), body.robots, self._registry
            )
        elif isinstance(body, FormationMissionCreate):
            plan, robots = plan_formation_mission(self._site.current(), body)
        else:
            plan, robots = plan_waypoints_mission(self._site.current(), body)
        now = time.time()
        m = Mission(
            id=uuid.uuid4().hex[:12],
            name=body.name or f"{body.type} with {', '.join(body.robots)}",
            type=body.type,
            state="draft",
            robot_ids=list(body.robots),
            params=body.params.model_dump(),
            created_by=created_by,
            created_at=now,
            updated_at=now,
            plan=plan,
            robots=robots,
            coverage=coverage_of(plan, body.params.model_dump()),
        )
        self.missions[m.id] = m
        transition = {"mission_id": m.id, "ts": now, "from_state": "", "to_state": "draft", "actor": created_by}
        self._writer.submit(store.insert_mission(mission_row(m, full=True), transition), after_rows=False)
        self._push(m)
        return mission_public(m)

    # -- actions --------------------------------------------------------------------------------------
    def get(self, mission_id: str) -> Mission:
        m = self.missions.get(mission_id)
        if m is None:
            raise ServiceError(404, f"unknown mission {mission_id!r}", "unknown_mission")
        return m

    async def history(self, mission_id: str) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
        """Its transitions and latest events, read on the writer after every write queued before: a mission
        just completed in memory shows its ``completed`` transition too (a direct read could come first)."""
        return await self._write(partial(store.history_on, mission_id=mission_id))

    def _check_ready(self, m: Mission, robot_ids: list[str]) -> None:
        now = time.time()
        problems = []
        for rid in robot_ids:
            st = self._registry.get(rid)
            if st is None:
                problems.append(f"{rid}: unknown")
                continue
            reasons = self._registry.not_ready(st, now)
            if "follow_path" not in st.capabilities.commands:
                reasons.append("cannot follow paths (agent too old)")
            if reasons:
                problems.append(f"{rid}: {', '.join(reasons)}")
        if problems:
            raise ServiceError(422, "robots not ready: " + "; ".join(problems), "robot_not_ready")
        for other in self.missions.values():
            if other.id != m.id and other.state in ("running", "paused"):
                busy = sorted(set(robot_ids) & {r.robot_id for r in other.robots if r.active})
                if busy:
                    raise ServiceError(409, f"{', '.join(busy)} already in mission {other.id}", "robot_in_mission")
        if self._estop.engaged:
            raise ServiceError(409, "the fleet e-stop is engaged", "estop_engaged")

    async def start(self, mission_id: str, actor: str, by: Actor | None = None) -> MissionPublic:
        """``by``: the operator starting it (their leases pass to the mission; None: ``actor`` by name)."""
        async with self._lock:
            m = self.get(mission_id)
            _expect(m, ("draft",), "start")
            self._check_ready(m, m.robot_ids)
            if m.type == "coverage":  # parts go to the robots by where they are now
                plan, robots = plan_coverage_mission(self._site.current(), m.params, m.robot_ids, self._registry)
            await self._take_leases(m, m.robot_ids, by or Actor(subject=actor, name=actor), "started")
            now = time.time()
            await self._claim_or_release(m, now)
            await self._open_run(m, by or Actor(subject=actor, name=actor))
            if m.type == "coverage":
                m.plan, m.robots = plan, robots
                m.coverage = coverage_of(m.plan, m.params)
            m.started_at = now
            self._transition(m, "running", actor, "", now)
            await self._step(m, now)  # a synchronized start: every first leg goes out in this step
            return mission_public(m)

    async def pause(self, mission_id: str, actor: str, reason: str = "") -> tuple[MissionPublic, bool]:
        """running -> paused. Through a replica that does not run it: asked of the owner (see :meth:`_ask`).
        Returns the mission and whether the pause is done (False: asked, not applied yet)."""
        async with self._lock:
            m = self.get(mission_id)
            _expect(m, ("running",), "pause")
            if not await self._ask(m, "pause", actor, reason):
                await self._claim(m, "paused", time.time())
                await self._halt(m, "paused", actor, reason or "paused by an operator")
                return mission_public(m), True
        return await self._await_owner(mission_id, ("paused", "aborted", "completed", "failed"))

    async def resume(self, mission_id: str, actor: str, rejoin: list[str], by: Actor | None = None) -> MissionPublic:
        async with self._lock:
            m = self.get(mission_id)
            _expect(m, ("paused",), "resume")
            unknown = [rid for rid in rejoin if m.robot(rid) is None]
            if unknown:
                raise ServiceError(422, f"not robots of this mission: {', '.join(unknown)}", "unknown_robot")
            going = [r.robot_id for r in m.robots if r.status == "paused" or r.robot_id in rejoin]
            self._check_ready(m, going)
            await self._take_leases(m, going, by or Actor(subject=actor, name=actor), "resumed")
            now = time.time()
            await self._claim_or_release(m, now)
            for r in m.robots:
                if r.robot_id in rejoin and r.status == "dropped":
                    self._event(m, "rejoin", r.robot_id, {"by": actor}, now)
                    r.status = "pending"
                elif r.status == "paused":
                    r.status = "pending"
                    r.index = max(r.index, min(r.reached, r.leg_end or r.index))
            self._transition(m, "running", actor, "", now)
            await self._step(m, now)
            return mission_public(m)

    async def abort(self, mission_id: str, actor: str, reason: str = "") -> tuple[MissionPublic, bool]:
        """draft, running or paused -> aborted; like :meth:`pause` through a replica that does not run it."""
        async with self._lock:
            m = self.get(mission_id)
            _expect(m, ("draft", "running", "paused"), "abort")
            if not await self._ask(m, "abort", actor, reason):
                await self._claim(m, "aborted", time.time())
                await self._halt(m, "aborted", actor, reason or "aborted by an operator")
                return mission_public(m), True
        return await self._await_owner(mission_id, ("aborted", "completed", "failed"))

    async def _ask(self, m: Mission, action: str, actor: str, reason: str) -> bool:
        """A pause or abort of a mission that another live replica runs: recorded in its row for that replica
        to apply (it reads it with its lease renewal, every second). True when asked; False when this replica
        may act itself. Safety does not wait for this: if the owner is dead its robots have stopped already
        (supervision), and the takeover pauses the mission."""
        now = time.time()
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
        asked_at = time.time()
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
                            self.missions[mission_id] = m = _from_row(row)
                            self._push(m)
                        return mission_public(m), True
            if time.monotonic() >= deadline:
                return mission_public(self.get(mission_id)), False
            await asyncio.sleep(0.1)

    async def _halt(self, m: Mission, state: str, actor: str, reason: str) -> None:
        """Stop every moving robot of the mission (stop needs no lease), then record the new state."""
        self._end_formation(m.id)  # before the stops: no drive of its may follow them
        now = time.time()
        for r in m.robots:
            if r.hold_command_id is not None and r.status != "moving":  # on its way back to its place
                await self._stop(r.robot_id, f"mission {m.id} {state}")
            r.hold_at, r.hold_command_id = None, None
            if r.status in ("moving", "waiting", "pending"):
                if r.status == "moving":
                    await self._stop(r.robot_id, f"mission {m.id} {state}")
                r.status, r.command_id = ("paused" if state == "paused" else "stopped"), None
            elif r.status == "paused" and state != "paused":
                r.status = "stopped"
        self._transition(m, state, actor, reason, now)
        await self._release_leases(m)

    # -- control leases -------------------------------------------------------------------------------
    async def _take_leases(self, m: Mission, robot_ids: list[str], by: Actor, verb: str) -> None:
        """Starting or resuming: the mission takes its robots' leases (all or none: 409 naming whoever else
        drives one), so that nobody else drives them while it runs and they never lapse mid-mission."""
        driver = self._leases.mission_actor(m.id, m.name, by, verb)
        await self._leases.take_for_mission(robot_ids, driver, by, partial(self._drives, m))
        self._drivers[m.id] = driver

    def _drives(self, m: Mission, robot_id: str) -> bool:
        """The mission holds a robot's lease while it runs and the robot is in it (not dropped out)."""
        r = m.robot(robot_id)
        return m.state == "running" and r is not None and (r.active or r.status == "done")

    async def _release_leases(self, m: Mission) -> None:
        """Paused or ended: a mission that sends nothing holds nothing (docs/missions.md says why)."""
        driver = self._drivers.pop(m.id, None)
        if driver is not None:
            await self._leases.release_mission(driver)

    async def _stop(self, robot_id: str, why: str) -> None:
        try:
            await self._commands.stop_now(robot_id, why)
        except (CommandError, ServiceError) as exc:
            log.warning("stop of %s for a mission failed: %s", robot_id, exc)

    # -- running --------------------------------------------------------------------------------------
    async def run(self) -> None:
        while True:
            await asyncio.sleep(TICK_S)
            try:
                async with self._lock:
                    now = time.time()
                    if now - self._renewed_at >= RENEW_S:  # first of all after a freeze: is it still ours?
                        await self._replicas(now)
                    for m in list(self.missions.values()):
                        if m.state == "running" and m.owner == self.server_id:
                            await self._step(m, now)
            except Exception:
                log.exception("mission tick failed")

    # -- replicas -------------------------------------------------------------------------------------
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
                    self.missions[mid] = _from_row(row)
                    self._push(self.missions[mid])
        self._renewed_at = now
        for orphan in await asyncio.to_thread(store.orphaned, self._engine, self.server_id, now, LEASE_S):
            await self._take_over(orphan, now)
        since, self._synced_at = self._synced_at, now
        for row in await asyncio.to_thread(store.load_changed, self._engine, since - MIRROR_MARGIN_S, self.server_id):
            m = self.missions.get(row["id"])
            ours = m is not None and m.owner == self.server_id and m.state == "running"
            if not ours and (m is None or row["updated_at"] > m.updated_at):
                self.missions[row["id"]] = _from_row(row)
                self._push(self.missions[row["id"]])

    async def _apply_asked(self, m: Mission, asked: dict[str, Any]) -> None:
        """A pause or abort asked through another replica: applied here, by the one that runs the mission, as
        if asked here (the actor is the operator who asked; the claim clears the request)."""
        state = "aborted" if asked.get("action") == "abort" else "paused"
        if m.state != "running":
            return
        try:
            await self._claim(m, state, time.time())
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
        m = _from_row(row)
        m.running_since = None
        _pause_robots(m)
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
            self.missions[m.id] = _from_row(row)
        fresh = self.missions[m.id]
        if fresh.state == "running" and fresh.owner not in (None, self.server_id):
            raise ServiceError(
                409,
                f"mission {m.id} runs on replica {fresh.owner}: act on it there (the fleet e-stop works everywhere)",
                "mission_on_other_replica",
            )
        raise ServiceError(409, f"the mission is {fresh.state} now (changed on another replica)", "bad_mission_state")

    async def _write(self, op: Any) -> Any:
        future = self._writer.submit(op, want_result=True, after_rows=False)
        assert future is not None
        return await asyncio.wrap_future(future)

    async def _step(self, m: Mission, now: float) -> None:
        if self._estop.engaged:
            await self._halt(m, "paused", SYSTEM, "fleet e-stop engaged")
            return
        if m.type == "formation":
            await self._step_formation(m, now)
            return
        for r in m.robots:
            if r.active:
                await self._alarm_pause(m, r, now)
        for r in m.robots:
            if not r.active:
                continue
            why = self._observe(r)
            if why is None and r.status == "moving" and r.command_id is not None:
                cmd = self._commands.cached(r.command_id)
                if cmd is None:
                    why = "its command was lost"
                elif cmd.status == "done":
                    r.index, r.status, r.command_id = r.leg_end, "pending", None
                elif cmd.status in FAILED_COMMAND:
                    why = f"{cmd.status}: {cmd.reason}"
                    if self._retry(m, r, cmd.status, cmd.reason, now):
                        why = None
            if why is not None:
                await self._drop(m, r, why, now)
        paused = m.extra.get("alarm_paused", [])
        for r in m.robots:
            if r.status in ("pending", "waiting") and r.robot_id not in paused:
                await self._next(m, r, now)
        self._watch_bystanders(m, now)
        if m.type == "coverage" and any(r.active for r in m.robots):
            for r in m.robots:
                if r.status in ("waiting", "done") and r.robot_id not in paused:
                    await self._hold(m, r)
        if all(not r.active for r in m.robots) and m.state == "running":
            for r in m.robots:  # nobody left to keep apart from: the finished robots stop holding their place
                if r.hold_command_id is not None:
                    await self._stop(r.robot_id, f"mission {m.id} ended")
                r.hold_at, r.hold_command_id = None, None
            dropped = [r.robot_id for r in m.robots if r.status == "dropped"]
            done = [r for r in m.robots if r.status == "done"]
            if not done or (m.type == "waypoints" and dropped):
                self._transition(m, "failed", SYSTEM, f"dropped out: {', '.join(dropped)}", now)
            else:
                self._transition(m, "completed", SYSTEM, "", now)
            await self._release_leases(m)
            return
        marks = tuple((r.status, r.index, r.reached, len(r.path)) for r in m.robots)
        if marks != m.extra.get("marks") or now - m.saved_at >= SAVE_EVERY_S:  # a waypoint passed: saved at once
            m.extra["marks"] = marks
            m.coverage.update(m.robots)
            self._save(m, now)

    def _retry(self, m: Mission, r: RobotRun, status: str, reason: str, now: float) -> bool:
        """A lost fix ends a leg, not the robot: the leg is sent again (a few times, a ``retry`` event each).
        Anything else (a lost link included: never resumed silently) drops the robot out."""
        retries = m.extra.setdefault("retries", {})
        # a leg refused because the robot has not heard this server's heartbeat yet (it just started) never began
        transient = reason.startswith("no_position") or (status == "rejected" and reason.startswith("unsupervised"))
        if not transient or retries.get(r.robot_id, 0) >= MAX_RETRIES:
            return False
        retries[r.robot_id] = retries.get(r.robot_id, 0) + 1
        r.index = max(r.index, min(r.reached, r.leg_end))
        r.status, r.command_id = "pending", None
        self._event(m, "retry", r.robot_id, {"reason": reason, "attempt": retries[r.robot_id]}, now)
        return True

    def _observe(self, r: RobotRun) -> str | None:
        """Record where a mission robot is now; why it must drop out (offline, held by its stop latch), or None."""
        st = self._registry.get(r.robot_id)
        if st is not None and st.position is not None:
            r.observe(st.position.x, st.position.y)
        if st is None or not st.online:
            return "offline"
        if st.hold is not None:
            return f"held: {st.hold.reason or st.hold.source}"
        return None

    async def _next(self, m: Mission, r: RobotRun, now: float) -> None:
        leg = r.next_leg()
        if leg is None:
            r.status = "done"
            self._event(m, "robot_done", r.robot_id, {}, now)
            return
        start, end = leg
        if r.gate_at is not None and start >= r.gate_at and r.gate_robot:
            gate = m.robot(r.gate_robot)
            if gate is not None and gate.active and gate.index < gate.head_pass:
                if r.status != "waiting":
                    r.status = "waiting"
                    self._event(m, "wait", r.robot_id, {"for": gate.robot_id, "why": "separation"}, now)
                return
        # the leg needs this replica's heartbeat: if it goes silent, the robot stops, whoever else beats
        args: dict[str, Any] = {
            "waypoints": r.path[start:end],
            "tolerance_m": LEG_TOLERANCE_M,
            "supervisor": self.server_id,
        }
        if m.params.get("speed"):
            args["max_speed"] = m.params["speed"]
        try:
            cmd = await self._commands.create(
                r.robot_id,
                CommandCreate(command="follow_path", args=args, source=f"mission:{m.id}"),
                self._drivers.get(m.id),  # under the mission's lease (an admin's takeover refuses the leg)
            )
        except (CommandError, ServiceError) as exc:
            await self._drop(m, r, f"leg refused: {exc}", now)
            return
        r.status, r.command_id, r.leg_end = "moving", cmd.id, end
        r.hold_at, r.hold_command_id = None, None  # the leg supersedes a hold's goto on the robot

    def _watch_bystanders(self, m: Mission, now: float) -> None:
        """Robots driven by hand near the mission are warned about, not steered: a robot in no running or paused
        mission that comes within the minimum separation + ``NEAR_MARGIN_M`` of one of this mission's robots
        gives a ``hand_near`` event (once per approach). The mission's paths do not know where it is."""
        limit = float(m.plan.get("min_separation_m", 0.3)) + NEAR_MARGIN_M
        ours = []
        for r in m.robots:
            st = self._registry.get(r.robot_id)
            pos = st.position if st is not None and st.online else None
            if (r.active or r.status == "done") and pos is not None and now - pos.ts <= NEAR_FIX_S:
                ours.append((r.robot_id, pos.x, pos.y))
        busy = {r.robot_id for o in self.missions.values() if o.state in ("running", "paused") for r in o.robots}
        near: dict[str, bool] = m.extra.setdefault("near", {})
        for st in self._registry.robots.values():
            pos = st.position
            if st.id in busy or not st.online or pos is None or now - pos.ts > NEAR_FIX_S:
                continue
            for rid, x, y in ours:
                d = math.hypot(pos.x - x, pos.y - y)
                key = f"{st.id}|{rid}"
                if d < limit and key not in near:
                    near[key] = True
                    detail = {"near": rid, "distance_m": _mm_below(d), "limit_m": round(limit, 3)}
                    self._event(m, "hand_near", st.id, detail, now)
                    log.warning("mission %s: hand-driven robot %s near %s (%.2f m)", m.id, st.id, rid, d)
                elif d > limit + NEAR_REARM_M:
                    near.pop(key, None)
        self._watch_own(m, now)

    def _watch_own(self, m: Mission, now: float) -> None:
        """Two robots of the mission closer than the minimum separation (a dropped robot drifting with its
        motors off, a trip to a part, a waypoints mission's crossing paths) give a ``too_close`` event, once per
        approach: the planner keeps them apart, and when that fails it is recorded, not hidden."""
        sep = float(m.plan.get("min_separation_m", 0.3))
        fixes = []
        for r in m.robots:
            st = self._registry.get(r.robot_id)
            pos = st.position if st is not None and st.online else None
            if pos is not None and now - pos.ts <= NEAR_FIX_S and r.status != "stopped":
                fixes.append((r.robot_id, pos.x, pos.y))
        close: dict[str, bool] = m.extra.setdefault("close", {})
        for i, (a, ax, ay) in enumerate(fixes):
            for b, bx, by in fixes[i + 1 :]:
                d = math.hypot(ax - bx, ay - by)
                key = f"{a}|{b}"
                if d < sep and key not in close:
                    close[key] = True
                    self._event(m, "too_close", a, {"near": b, "distance_m": _mm_below(d), "limit_m": sep}, now)
                    log.warning("mission %s: %s and %s %.2f m apart (minimum %.2f m)", m.id, a, b, d, sep)
                elif d > sep + NEAR_REARM_M:
                    close.pop(key, None)

    async def _hold(self, m: Mission, r: RobotRun) -> None:
        """A robot waiting for its turn at a cut, or finished while others still sweep, keeps its place: with
        its motors off the current would carry it into a neighbour's part (the separation rule assumes it
        stays). Once it drifted ``HOLD_DRIFT_M`` it gets a short ``goto`` back, supervised like a leg."""
        st = self._registry.get(r.robot_id)
        if st is None or not st.online or st.position is None or st.hold is not None:
            return
        here = [st.position.x, st.position.y]
        if r.hold_at is None:
            r.hold_at = here
            return
        if r.hold_command_id is not None:
            cmd = self._commands.cached(r.hold_command_id)
            if cmd is not None and cmd.status not in ("done", *FAILED_COMMAND):
                return  # on its way back
            r.hold_command_id = None
        if math.dist(here, r.hold_at) < HOLD_DRIFT_M:
            return
        args = {
            "x": r.hold_at[0],
            "y": r.hold_at[1],
            "tolerance_m": HOLD_TOLERANCE_M,
            "supervisor": self.server_id,
        }
        try:
            cmd = await self._commands.create(
                r.robot_id,
                CommandCreate(command="goto", args=args, source=f"mission:{m.id}:hold"),
                self._drivers.get(m.id),  # under the mission's lease, as its legs
            )
        except (CommandError, ServiceError) as exc:
            log.warning("mission %s: %s could not hold its place: %s", m.id, r.robot_id, exc)
            return
        r.hold_command_id = cmd.id

    async def _alarm_pause(self, m: Mission, r: RobotRun, now: float) -> None:
        """A critical alarm of a robot in a mission pauses that robot and keeps its work for it: it carries on
        from where it stopped once the alarm is cleared. ``offline_in_mission`` only notifies (a robot that
        went offline drops out: :meth:`_drop`)."""
        paused: list[str] = m.extra.setdefault("alarm_paused", [])
        critical = [kind for kind in self._alarms.critical_kinds(r.robot_id) if kind != OFFLINE_IN_MISSION]
        if critical and r.robot_id not in paused:
            paused.append(r.robot_id)
            if r.status == "moving":
                r.index = max(r.index, min(r.reached, r.leg_end))
                r.status, r.command_id = "pending", None
                await self._stop(r.robot_id, f"mission {m.id}: critical alarm {critical[0]}")
            self._event(m, "alarm_pause", r.robot_id, {"alarms": critical}, now)
            log.warning("mission %s: %s paused by its critical alarm %s", m.id, r.robot_id, critical[0])
        elif not critical and r.robot_id in paused:
            paused.remove(r.robot_id)
            self._event(m, "alarm_resume", r.robot_id, {}, now)

    async def _drop(self, m: Mission, r: RobotRun, why: str, now: float) -> None:
        """A robot that failed, went offline or is held: its remaining area goes to the others at once."""
        was_moving = r.status == "moving"
        r.status, r.reason, r.command_id = "dropped", why, None
        self._event(m, "dropout", r.robot_id, {"reason": why}, now)
        if why == "offline":  # the alarm only notifies: the re-plan below is the reaction
            self._alarms.raise_(
                r.robot_id, OFFLINE_IN_MISSION, f"offline during mission {m.name or m.id}", {"mission_id": m.id}
            )
        log.warning("mission %s: %s dropped out (%s)", m.id, r.robot_id, why)
        st = self._registry.get(r.robot_id)
        if was_moving and st is not None and st.online:
            await self._stop(r.robot_id, f"mission {m.id}: dropped out")
        if m.type != "coverage":
            return
        survivors = [
            x for x in m.robots if x is not r and (x.active or x.status == "done") and self._online(x.robot_id)
        ]
        if not survivors:
            await self._halt(m, "paused", SYSTEM, f"no robot left to take over {r.robot_id}'s area")
            return
        m.coverage.update(m.robots)
        overlap = float(m.params.get("overlap", 0.0))
        stopped = [x.robot_id for x in m.robots if x.status == "dropped"]
        clear = [(p.x, p.y) for rid in stopped if (st := self._registry.get(rid)) and st.online and (p := st.position)]
        given = replan(r, survivors, m.coverage, overlap, float(m.plan.get("min_separation_m", 0.3)), clear)
        self._event(m, "replan", r.robot_id, {"to": [x.robot_id for x in survivors][:given], "parts": given}, now)

    def _online(self, robot_id: str) -> bool:
        return (st := self._registry.get(robot_id)) is not None and st.online and st.hold is None

    # -- formation --------------------------------------------------------------------------------------
    async def _step_formation(self, m: Mission, now: float) -> None:
        """The slow half of a formation mission (the fast half is its FormationDriver): the leader's path
        command, dropouts, the end (the path done, ``duration_s`` reached, or the leader gone)."""
        form = m.plan["formation"]
        leader = m.robot(form["leader"])
        assert leader is not None
        driver = self._formations.get(m.id)
        for r in m.robots:
            if not r.active:
                continue
            why = self._observe(r)
            if why is None and driver is not None and r.robot_id in driver.refused:
                why = f"drive refused: {driver.refused[r.robot_id]}"
            elif why is None and r is leader and r.status == "moving" and r.command_id is not None:
                cmd = self._commands.cached(r.command_id)
                if cmd is None:
                    why = "its command was lost"
                elif cmd.status == "done":
                    r.index, r.reached, r.status, r.command_id = len(r.path), len(r.path), "done", None
                elif cmd.status in FAILED_COMMAND:
                    why = f"{cmd.status}: {cmd.reason}"
                    if self._retry(m, r, cmd.status, cmd.reason, now):
                        why = None
            if why is not None:
                if driver is not None and r is not leader:
                    driver.laws.pop(r.robot_id, None)  # no more drives to it
                await self._drop(m, r, why, now)
        followers = [r for r in m.robots if r is not leader]
        end = None
        if leader.status == "dropped":
            end = ("failed", f"the leader {leader.robot_id} dropped out: {leader.reason}")
        elif not any(r.active for r in followers):
            end = ("failed", "every follower dropped out")
        elif leader.status == "done":
            end = ("completed", "the leader's path is done")
        elif m.params.get("duration_s") and m.elapsed(now) >= float(m.params["duration_s"]):
            end = ("completed", f"ran for {float(m.params['duration_s']):g} s")
        if end is not None:
            self._end_formation(m.id)
            for r in m.robots:
                if r.active:
                    if r.status == "moving" and self._online(r.robot_id):
                        await self._stop(r.robot_id, f"mission {m.id} {end[0]}")
                    r.status, r.command_id = "done", None
            self._transition(m, end[0], SYSTEM, end[1], now)
            return
        if leader.status == "pending":
            await self._send_leader_path(m, leader, now)
        for r in followers:
            if r.status == "pending":
                r.status = "moving"
        if m.state == "running" and (driver is None or not driver.running):
            self._start_formation(m, form)
        marks = tuple((r.status, r.index, r.reached) for r in m.robots)
        if marks != m.extra.get("marks") or now - m.saved_at >= SAVE_EVERY_S:
            m.extra["marks"] = marks
            self._save(m, now)

    async def _send_leader_path(self, m: Mission, leader: RobotRun, now: float) -> None:
        """The leader's path as one ``follow_path`` (looping, at the mission's speed), started at the waypoint
        after the one nearest to the leader, so that it does not turn back for the first one."""
        path = leader.path
        st = self._registry.get(leader.robot_id)
        if m.params.get("loop", True) and st is not None and st.position is not None and len(path) > 1:
            x, y = st.position.x, st.position.y
            near = min(range(len(path)), key=lambda i: (path[i][0] - x) ** 2 + (path[i][1] - y) ** 2)
            path = path[near + 1 :] + path[: near + 1]
        else:
            path = path[leader.index :] or path[-1:]
        args: dict[str, Any] = {
            "waypoints": path,
            "tolerance_m": LEG_TOLERANCE_M,
            "loop": bool(m.params.get("loop", True)),
            "max_speed": float(m.params.get("speed") or 0.08),
            "supervisor": self.server_id,  # as every leg: the leader stops if this replica goes silent
        }
        try:
            cmd = await self._commands.create(
                leader.robot_id,
                CommandCreate(command="follow_path", args=args, source=f"mission:{m.id}"),
                self._drivers.get(m.id),  # under the mission's lease
            )
        except (CommandError, ServiceError) as exc:
            await self._drop(m, leader, f"path refused: {exc}", now)
            return
        leader.status, leader.command_id, leader.leg_end = "moving", cmd.id, len(leader.path)

    def _start_formation(self, m: Mission, form: dict[str, Any]) -> None:
        self._end_formation(m.id)
        slots = {
            r.robot_id: (float(form["slots"][r.robot_id][0]), float(form["slots"][r.robot_id][1]))
            for r in m.robots
            if r.robot_id in form["slots"] and r.active
        }

        async def send(robot_id: str, linear: float, angular: float) -> str | None:
            # the mission as this replica knows it now (a sync from the database replaces the object): only a
            # running mission that this replica still owns drives its followers
            now_m = self.missions.get(m.id)
            if now_m is None or now_m.state != "running" or now_m.owner != self.server_id:
                return None
            args = {"linear": linear, "angular": angular, "duration_s": DRIVE_DEADMAN_S}
            try:
                await self._commands.create(
                    robot_id,
                    CommandCreate(command="drive", args=args, ttl_s=1.0, source=f"mission:{m.id}"),
                    self._drivers.get(m.id),  # under the mission's lease
                )
            except (CommandError, ServiceError) as exc:
                return str(exc)
            return None

        driver = FormationDriver(leader=form["leader"], slots=slots, registry=self._registry, send=send)
        self._formations[m.id] = driver
        driver.start(f"formation-{m.id}")

    def _end_formation(self, mission_id: str) -> None:
        driver = self._formations.pop(mission_id, None)
        if driver is not None:
            driver.stop()

    async def close(self) -> None:
        """Stop every formation's fast loop and finish closing runs (the server is shutting down)."""
        drivers = list(self._formations.values())
        self._formations.clear()
        for driver in drivers:
            driver.stop()
            await driver.wait_stopped()
        if self._closing:
            await asyncio.gather(*self._closing, return_exceptions=True)

    # -- records --------------------------------------------------------------------------------------
    def _transition(self, m: Mission, state: str, actor: str, reason: str, now: float) -> None:
        if state != "running":
            self._end_formation(m.id)
        if state in ENDED and m.run_id is not None:
            task = asyncio.get_running_loop().create_task(self._close_run(m.id, m.run_id))
            self._closing.add(task)
            task.add_done_callback(self._closing.discard)
        previous = m.state
        if previous == "running" and m.running_since is not None:
            m.run_s += now - m.running_since
            m.running_since = None
        if state == "running":
            m.running_since = now
        if state in ENDED:
            m.ended_at = now
        m.state, m.reason, m.updated_at = state, reason, now
        m.coverage.update(m.robots)
        transition = {
            "mission_id": m.id,
            "ts": now,
            "from_state": previous,
            "to_state": state,
            "actor": actor,
            "reason": reason,
        }
        self._writer.submit(store.update_mission(m.id, mission_row(m), transition, self.server_id), after_rows=False)
        m.saved_at = now
        log.info("mission %s: %s -> %s by %s %s", m.id, previous, state, actor, reason)
        self._push(m)

    async def _open_run(self, m: Mission, by: Actor) -> None:
        """Starting: the mission records its robots in a run of its own (tag ``mission``), open until it ends.
        A run that cannot be opened is an event, never a reason not to start."""
        body = RunCreate(
            name=f"mission {m.name}"[:200], notes=f"opened by mission {m.id}", tags=["mission"], robots=m.robot_ids
        )
        try:
            run = await self._runs.start(by, body, self._site.version())
        except ServiceError as exc:
            self._event(m, "run_not_opened", None, {"reason": exc.detail}, time.time())
            return
        m.run_id = run.id
        self._event(m, "run_opened", None, {"run_id": run.id}, time.time())

    async def _close_run(self, mission_id: str, run_id: int) -> None:
        """Ended: stop the run the mission opened (if nobody stopped it by hand already)."""
        try:
            await self._runs.stop(run_id)
        except ServiceError as exc:
            if exc.code != "run_ended":
                log.warning("mission %s: its run %d was not stopped: %s", mission_id, run_id, exc.detail)
        except Exception:
            log.exception("mission %s: stopping its run %d failed", mission_id, run_id)

    def _save(self, m: Mission, now: float) -> None:
        m.saved_at = now
        self._writer.submit(store.update_mission(m.id, mission_row(m), owner=self.server_id), after_rows=False)
        self._push(m)

    def _event(self, m: Mission, kind: str, robot_id: str | None, detail: dict[str, Any], now: float) -> None:
        values = {"mission_id": m.id, "ts": now, "kind": kind, "robot_id": robot_id, "detail": detail}
        self._writer.submit(store.insert_event(values), after_rows=False)
        self._hub.publish_control({"type": "mission_event", "mission_id": m.id, "event": values})

    def _push(self, m: Mission) -> None:
        self._hub.publish_control({"type": "mission", "mission": mission_public(m).model_dump(mode="json")})


def _mm_below(d: float) -> float:
    """A distance to the millimetre, rounded down: one just under the limit (0.2996 m) must not read as the
    limit itself (0.3 m "closer than 0.3 m", seen in a clean-clone run)."""
    return math.floor(d * 1000) / 1000


def _expect(m: Mission, states: tuple[str, ...], action: str) -> None:
    if m.state not in states:
        raise ServiceError(409, f"cannot {action} a {m.state} mission", "bad_mission_state")


def _from_row(row: dict[str, Any]) -> Mission:
    """A mission as its row holds it (loaded at start, taken over, or mirrored from another replica)."""
    progress = row["progress"] or {}
    m = Mission(
        id=row["id"],
        name=row["name"],
        type=row["type"],
        state=row["state"],
        robot_ids=list(row["robots"]),
        params=row["params"],
        created_by=row["created_by"],
        created_at=row["created_at"],
        updated_at=row["updated_at"],
        plan=row["plan"],
        robots=[RobotRun.from_json(d) for d in progress.get("robots", [])],
        coverage=coverage_of(row["plan"], row["params"]),
        reason=row["reason"],
        started_at=row["started_at"],
        ended_at=row["ended_at"],
        run_s=row["run_s"],
        owner=row.get("owner"),
        requested=row.get("requested"),
        run_id=progress.get("run_id"),
    )
    if m.state == "running":  # a mirror counts its running time from the last save
        m.running_since = row["updated_at"]
    m.coverage.update(m.robots)
    return m


def _pause_robots(m: Mission) -> None:
    """Robots that were under way when their replica stopped: stopped, to carry on from there on Resume."""
    for r in m.robots:
        if r.status in ("moving", "waiting", "pending"):
            r.status, r.command_id = "paused", None
