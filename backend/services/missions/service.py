"""Missions: create (plan), start, pause, resume, abort; run them (send legs, watch acks, positions and
dropouts); store every transition; survive a restart as ``paused``. docs/missions.md explains the design.

The service is one class built from its parts: the book (book.py: records, leases, halting), the replicas'
ownership (replicas.py), the stepping of legs (stepping.py) and of formations (formation_stepping.py)."""

from __future__ import annotations

import asyncio
import time
import uuid
from collections.abc import Callable
from functools import partial
from typing import Any

from backend.core.errors import ServiceError
from backend.schemas.missions import (
    CoverageMissionCreate,
    FormationMissionCreate,
    MissionPublic,
    WaypointsMissionCreate,
)
from backend.services.access.audit import Actor
from backend.services.missions.book import SYSTEM, expect_state, log, mission_from_row, pause_robots
from backend.services.missions.coverage_feed import PUSH_S, CoverageFeed
from backend.services.missions.formation_stepping import FormationStepping
from backend.services.missions.planning import (
    check_coverage_mission,
    plan_coverage_mission,
    plan_formation_mission,
    plan_waypoints_mission,
    positions_of,
)
from backend.services.missions.record import Mission, coverage_of, mission_public, mission_row, stored_coverage
from backend.services.missions.replicas import RENEW_S, ReplicaOwnership
from backend.services.missions.state import Coverage, MissionRobot
from backend.services.missions.sweep import SweptView
from backend.store import missions as store

TICK_S = 0.2


class MissionService(ReplicaOwnership, FormationStepping, CoverageFeed):
    def load(self, rows: list[dict[str, Any]]) -> None:
        """A mission that this replica was running when it stopped is paused, with the reason: the robots
        stopped when its heartbeat did (supervision), and an operator decides when it carries on. One that
        another replica runs is mirrored (the takeover of a silent replica's missions: :meth:`_replicas`)."""
        now = self._clock()
        for row in rows:
            m = mission_from_row(row)
            self.missions[m.id] = m
            if m.state == "running" and m.owner in (None, self.server_id):
                m.owner, m.running_since = self.server_id, None  # the time it was down is not running time
                pause_robots(m)
                self._transition(m, "paused", SYSTEM, "server restarted: the robots stopped without supervision", now)
                self._leases.forget_mission(m.id, "server restarted")

    async def create(
        self, body: CoverageMissionCreate | WaypointsMissionCreate | FormationMissionCreate, created_by: str
    ) -> MissionPublic:
        """Checked here (a coverage plan against its limits, in milliseconds), planned on the planner pool."""
        unknown = [r for r in body.robots if self._registry.get(r) is None]
        if unknown:
            # 422 naming the field: the body names robots the server has never seen (a 404 would say the
            # mission route itself is missing); schemathesis is told so in tests/backend/api/schemathesis.toml
            raise ServiceError(422, f"robots: unknown robots: {', '.join(unknown)}", "unknown_robot")
        site = self._site.current()
        plan_it: Callable[[], tuple[dict[str, Any], list[MissionRobot]]]
        if isinstance(body, CoverageMissionCreate):
            job = check_coverage_mission(site, body.params.model_dump(), len(body.robots))
            plan_it = partial(plan_coverage_mission, job, list(body.robots), positions_of(body.robots, self._registry))
        elif isinstance(body, FormationMissionCreate):
            plan_it = partial(plan_formation_mission, site, body)
        else:
            plan_it = partial(plan_waypoints_mission, site, body)
        params = body.params.model_dump()
        plan, robots = await self.planner.run(plan_it)
        now = self._clock()
        m = Mission(
            id=uuid.uuid4().hex[:12],
            name=body.name or f"{body.type} with {', '.join(body.robots)}",
            type=body.type,
            state="draft",
            robot_ids=list(body.robots),
            params=params,
            created_by=created_by,
            created_at=now,
            updated_at=now,
            plan=plan,
            robots=robots,
            coverage=stored_coverage(plan, params, {}),  # a draft's grid is built when it starts (or is asked)
        )
        self.missions[m.id] = m
        transition = {"mission_id": m.id, "ts": now, "from_state": "", "to_state": "draft", "actor": created_by}
        self._writer.submit(store.insert_mission(mission_row(m, full=True), transition), after_rows=False)
        self._push(m)
        return mission_public(m)

    async def history(self, mission_id: str) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
        """Its transitions and latest events, read on the writer after every write queued before: a mission
        just completed in memory shows its ``completed`` transition too (a direct read could come first)."""
        return await self._write(partial(store.history_on, mission_id=mission_id))

    async def coverage_view(self, mission_id: str) -> tuple[SweptView | None, float]:
        """What the mission's tracks swept now (a copy of its grid, to draw on the planner pool) and its covered
        fraction. A mission read from its row gets its grid built on the pool first (503 when it is full)."""
        cov = await self._coverage_ready(self.get(mission_id), queued=False)
        return cov.view(), cov.fraction

    def _check_ready(self, m: Mission, robot_ids: list[str]) -> None:
        now = self._clock()
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
            expect_state(m, ("draft",), "start")
            self._check_ready(m, m.robot_ids)
            if m.type == "coverage":  # parts go to the robots by where they are now
                job = check_coverage_mission(self._site.current(), m.params, len(m.robot_ids))
                where = positions_of(m.robot_ids, self._registry)
                plan, robots, coverage = await self.planner.run(
                    planned, partial(plan_coverage_mission, job, m.robot_ids, where), m.params
                )
            await self._take_leases(m, m.robot_ids, by or Actor(subject=actor, name=actor), "started")
            now = self._clock()
            await self._claim_or_release(m, now)
            await self._open_run(m, by or Actor(subject=actor, name=actor))
            if m.type == "coverage":
                m.plan, m.robots, m.coverage = plan, robots, coverage
            await self._go(m, actor, now)
            return mission_public(m)

    async def _go(self, m: Mission, actor: str, now: float) -> None:
        m.started_at = now
        self._transition(m, "running", actor, "", now)
        await self._step(m, now)  # a synchronized start: every first leg goes out in this step

    async def start_in_twin(self, mission_id: str, actor: str) -> None:
        """A rehearsal's start (services/rehearsal): a draft as :meth:`start` (a coverage mission planned from
        where its robots are now), a paused mission as :meth:`resume`; no readiness, leases, replicas or run:
        the twin has none of them."""
        async with self._lock:
            m = self.get(mission_id)
            now = self._clock()
            if m.state == "paused":
                self._rejoin(m, [], actor, now)
                m.owner = self.server_id
                self._transition(m, "running", actor, "", now)
                await self._step(m, now)
                return
            expect_state(m, ("draft",), "rehearse")
            m.owner = self.server_id
            if m.type == "coverage":
                job = check_coverage_mission(self._site.current(), m.params, len(m.robot_ids))
                where = positions_of(m.robot_ids, self._registry)
                plan_it = partial(plan_coverage_mission, job, m.robot_ids, where)
                m.plan, m.robots, m.coverage = await self.planner.run(planned, plan_it, m.params)
            await self._go(m, actor, now)

    async def pause(self, mission_id: str, actor: str, reason: str = "") -> tuple[MissionPublic, bool]:
        """running -> paused. Through a replica that does not run it: asked of the owner (see :meth:`_ask`).
        Returns the mission and whether the pause is done (False: asked, not applied yet)."""
        async with self._lock:
            m = self.get(mission_id)
            expect_state(m, ("running",), "pause")
            if not await self._ask(m, "pause", actor, reason):
                await self._claim(m, "paused", self._clock())
                await self._halt(m, "paused", actor, reason or "paused by an operator")
                return mission_public(m), True
        return await self._await_owner(mission_id, ("paused", "aborted", "completed", "failed"))

    async def resume(self, mission_id: str, actor: str, rejoin: list[str], by: Actor | None = None) -> MissionPublic:
        async with self._lock:
            m = self.get(mission_id)
            expect_state(m, ("paused",), "resume")
            unknown = [rid for rid in rejoin if m.robot(rid) is None]
            if unknown:
                raise ServiceError(422, f"not robots of this mission: {', '.join(unknown)}", "unknown_robot")
            going = [r.robot_id for r in m.robots if r.status == "paused" or r.robot_id in rejoin]
            self._check_ready(m, going)
            await self._take_leases(m, going, by or Actor(subject=actor, name=actor), "resumed")
            now = self._clock()
            await self._claim_or_release(m, now)
            self._rejoin(m, rejoin, actor, now)
            self._transition(m, "running", actor, "", now)
            await self._step(m, now)
            return mission_public(m)

    def _rejoin(self, m: Mission, rejoin: list[str], actor: str, now: float) -> None:
        """Resuming: the paused robots, and the dropped ones named in ``rejoin``, carry on where they stopped."""
        for r in m.robots:
            if r.robot_id in rejoin and r.status == "dropped":
                self._event(m, "rejoin", r.robot_id, {"by": actor}, now)
                r.status = "pending"
            elif r.status == "paused":
                r.status = "pending"
                r.index = max(r.index, min(r.reached, r.leg_end or r.index))

    async def abort(self, mission_id: str, actor: str, reason: str = "") -> tuple[MissionPublic, bool]:
        """draft, running or paused -> aborted; like :meth:`pause` through a replica that does not run it."""
        async with self._lock:
            m = self.get(mission_id)
            expect_state(m, ("draft", "running", "paused"), "abort")
            if not await self._ask(m, "abort", actor, reason):
                await self._claim(m, "aborted", self._clock())
                await self._halt(m, "aborted", actor, reason or "aborted by an operator")
                return mission_public(m), True
        return await self._await_owner(mission_id, ("aborted", "completed", "failed"))

    async def run(self) -> None:
        """The server's mission loop: a step every ``TICK_S`` of the real clock, and the swept areas that
        changed pushed to the live socket every ``PUSH_S`` (coverage_feed.py)."""
        pushed_at = 0.0
        while True:
            await asyncio.sleep(TICK_S)
            try:
                await self.tick(self._clock())
            except Exception:
                log.exception("mission tick failed")
            if time.monotonic() - pushed_at >= PUSH_S:
                pushed_at = time.monotonic()
                try:
                    await self.push_coverage()
                except Exception:
                    log.exception("pushing the swept areas failed")

    async def tick(self, now: float) -> None:
        """One step of every mission this replica runs, at ``now`` (the twin calls it on a virtual clock)."""
        async with self._lock:
            if now - self._renewed_at >= RENEW_S:  # first of all after a freeze: is it still ours?
                await self._replicas(now)
            await self._step_owned(now)

    def keep_rehearsal(self, mission_id: str, rehearsal: dict[str, Any]) -> None:
        """A rehearsal's prediction, kept with a draft or paused mission (stored: another replica may start it)."""
        m = self.get(mission_id)
        m.rehearsal = rehearsal
        self._writer.submit(store.update_mission(m.id, {"progress": mission_row(m)["progress"]}), after_rows=False)
        self._push(m)

    async def end_in_twin(self, mission_id: str, reason: str) -> None:
        """A rehearsal that reached its time limit: the mission aborted as :meth:`abort` would, locally."""
        async with self._lock:
            await self._halt(self.get(mission_id), "aborted", SYSTEM, reason)

    async def step_in_twin(self, now: float) -> None:
        """The twin's tick (services/rehearsal): :meth:`tick` without the replicas' ownership (it has one)."""
        async with self._lock:
            await self._step_owned(now)

    async def _step_owned(self, now: float) -> None:
        for m in list(self.missions.values()):
            if m.state == "running" and m.owner == self.server_id:
                await self._step(m, now)

    async def _step(self, m: Mission, now: float) -> None:
        if self._estop.engaged:
            await self._halt(m, "paused", SYSTEM, "fleet e-stop engaged")
            return
        if m.type == "formation":
            await self._step_formation(m, now)
        else:
            await self._step_legs(m, now)

    async def close(self) -> None:
        """Stop every formation's fast loop and finish closing runs (the server is shutting down)."""
        drivers = list(self._formations.values())
        self._formations.clear()
        for driver in drivers:
            driver.stop()
            await driver.wait_stopped()
        if self._closing:
            await asyncio.gather(*self._closing, return_exceptions=True)
        await asyncio.to_thread(self.planner.close)  # a plan under way ends (each is bounded); none starts


def planned(
    plan_it: Callable[[], tuple[dict[str, Any], list[MissionRobot]]], params: dict[str, Any]
) -> tuple[dict[str, Any], list[MissionRobot], Coverage]:
    """A plan and the coverage it is measured against (its region built from the plan's rings): both on the
    planner's thread."""
    plan, robots = plan_it()
    return plan, robots, coverage_of(plan, params)
