"""A mission's book: what every part of the mission service shares (the missions, their records and events,
the leases they drive under, halting them), apart from stepping them and from the replicas' ownership.
The service is built up from it: :class:`MissionBook` <- replicas.py, stepping.py, formation_stepping.py
<- service.py."""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from functools import partial
from typing import Any

from sqlalchemy import Engine

from backend.core.errors import ServiceError
from backend.core.workpool import WorkPool
from backend.schemas.runs import RunCreate
from backend.services.access.audit import Actor
from backend.services.control.args import CommandError
from backend.services.control.commands import CommandService
from backend.services.control.leases import LeaseService
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.services.missions.formation import FormationDriver
from backend.services.missions.record import Mission, mission_public, mission_row, stored_coverage
from backend.services.missions.site_source import SiteSource
from backend.services.missions.state import Coverage, MissionRobot, built_coverage
from backend.services.runs.recorder import RunService
from backend.services.safety.alarms import AlarmService
from backend.services.safety.estop import EStopService
from backend.store import missions as store
from backend.store.writer import BatchWriter

log = logging.getLogger("backend.services.missions")

ENDED = ("completed", "aborted", "failed")
SYSTEM = "system"
FAILED_COMMAND = ("failed", "aborted", "rejected", "expired", "timeout")
#: a mission's progress is saved at least this often (and at once when a waypoint is passed)
SAVE_EVERY_S = 2.0
LEG_TOLERANCE_M = 0.08


class MissionBook:
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
        planner: WorkPool,
        clock: Callable[[], float] = time.time,
    ) -> None:
        #: plans, re-plans and coverage pictures are built here, never on the event loop (closed with the service)
        self.planner = planner
        #: the time of every record and step (the twin of a rehearsal passes a virtual one)
        self._clock = clock
        self._runs = runs
        #: runs being closed (a mission that ended stops the run it opened)
        self._closing: set[asyncio.Task[None]] = set()
        self._engine = engine
        #: this replica's id (its heartbeat's server_id): it owns the missions it runs, and their legs name it
        self.server_id = server_id
        self._renewed_at = 0.0
        self._synced_at = clock()
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
        #: mission id -> the swept area's GeoJSON last pushed on the live socket (coverage_feed.py)
        self.swept_pushed: dict[str, bytes] = {}

    def get(self, mission_id: str) -> Mission:
        m = self.missions.get(mission_id)
        if m is None:
            raise ServiceError(404, f"unknown mission {mission_id!r}", "unknown_mission")
        return m

    async def _write(self, op: Any) -> Any:
        """Ownership and reads between replicas: done now or refused (503), never replayed later with a
        stale time while the database was away (they are asked again on the next tick)."""
        future = self._writer.submit(op, want_result=True, after_rows=False, retry=False)
        assert future is not None
        return await asyncio.wrap_future(future)

    async def _halt(self, m: Mission, state: str, actor: str, reason: str) -> None:
        """Stop every moving robot of the mission (stop needs no lease), then record the new state."""
        self._end_formation(m.id)  # before the stops: no drive of its may follow them
        now = self._clock()
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

    async def _take_leases(self, m: Mission, robot_ids: list[str], by: Actor, verb: str) -> None:
        """Starting or resuming: the mission takes its robots' leases (all or none: 409 naming whoever else
        drives one), so that nobody else drives them while it runs and they never lapse mid-mission."""
        driver = self._leases.mission_actor(m.id, m.name, by, verb)
        # driving from here on: the leases' renewal may ask while the start still waits for the database (the
        # claim, the run), before the mission is ``running``; it must not give the leases straight back
        self._drivers[m.id] = driver
        try:
            await self._leases.take_for_mission(robot_ids, driver, by, partial(self._drives, m))
        except BaseException:
            self._drivers.pop(m.id, None)
            raise

    def _drives(self, m: Mission, robot_id: str) -> bool:
        """The mission holds a robot's lease from its start or resume until it pauses
        (:meth:`_release_leases`) or ends, while the robot is in it (not dropped out)."""
        r = m.robot(robot_id)
        return m.id in self._drivers and m.state not in ENDED and r is not None and (r.active or r.status == "done")

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

    def _end_formation(self, mission_id: str) -> None:
        driver = self._formations.pop(mission_id, None)
        if driver is not None:
            driver.stop()

    def _transition(self, m: Mission, state: str, actor: str, reason: str, now: float) -> None:
        if state != "running":
            self._end_formation(m.id)
        if state in ENDED and m.run_id is not None:
            ender = Actor(subject=f"mission:{m.id}", name=f"mission {m.name[:80]} ({state} by {actor})"[:160])
            task = asyncio.get_running_loop().create_task(self._close_run(m.id, m.run_id, ender))
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
        if state in ENDED:  # its figures stay; its grid is built again on the pool if its swept area is asked
            m.coverage = m.coverage.figures_only()
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
        notes = f"opened by mission {m.id}" + rehearsal_note(m.rehearsal)
        body = RunCreate(name=f"mission {m.name}"[:200], notes=notes[:2000], tags=["mission"], robots=m.robot_ids)
        try:
            run = await self._runs.start(by, body, self._site.version(), mission_id=m.id)
        except ServiceError as exc:
            self._event(m, "run_not_opened", None, {"reason": exc.detail}, self._clock())
            return
        m.run_id = run.id
        self._event(m, "run_opened", None, {"run_id": run.id}, self._clock())

    async def _close_run(self, mission_id: str, run_id: int, by: Actor) -> None:
        """Ended: stop the run the mission opened (if nobody stopped it by hand already; audited as ``by``)."""
        try:
            await self._runs.stop(by, run_id)
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

    async def _coverage_ready(self, m: Mission, queued: bool) -> Coverage:
        """The mission's coverage with its grid, up to date: one with only its row's figures (read from a row,
        a draft, an ended mission) gets its grid built on the planner pool (``queued``: the server's own need,
        waiting its turn; else a request's, refused when the pool is full), its tracks marked up to where they
        are now; from then on each update adds the rest. An ended mission does not keep it (memory)."""
        cov = m.coverage
        if not cov.deferred:
            cov.update(m.robots)
            return cov
        tracks = [(r.robot_id, r.track, len(r.track)) for r in m.robots]  # sliced on the pool, not copied here
        job = partial(built_coverage, cov, tracks)
        built = await (self.planner.run_queued(job) if queued else self.planner.run(job))
        built.update(m.robots)  # the points added while it was built
        if m.coverage is cov and m.state not in ENDED:  # not replaced meanwhile (a mirror's newer row, a start)
            m.coverage = built
        return built

    def _push(self, m: Mission) -> None:
        self._hub.publish_control({"type": "mission", "mission": mission_public(m).model_dump(mode="json")})


def rehearsal_note(rehearsal: dict[str, Any] | None) -> str:
    """The rehearsal a mission was started with, in its run's notes (empty when it was not rehearsed)."""
    if not rehearsal:
        return ""
    p = rehearsal.get("predicted", {})
    covered = p.get("covered_fraction")
    parts = [
        f"duration {p.get('duration_s')} s",
        *([f"coverage {covered:.3f}"] if isinstance(covered, int | float) else []),
        f"closest approach {p.get('min_separation_m')} m",
        f"{p.get('filter_interventions')} filter interventions",
        f"{p.get('blocked_legs')} blocked legs",
        f"{p.get('collisions')} contacts",
        f"{p.get('fence_violations')} fence violations",
    ]
    return f"; rehearsed with seed {rehearsal.get('seed')}: predicted {', '.join(parts)}"


def mm_below(d: float) -> float:
    """A distance to the millimetre, rounded down: one just under the limit (0.2996 m) must not read as the
    limit itself (0.3 m "closer than 0.3 m", seen in a clean-clone run)."""
    return math.floor(d * 1000) / 1000


def expect_state(m: Mission, states: tuple[str, ...], action: str) -> None:
    if m.state not in states:
        raise ServiceError(409, f"cannot {action} a {m.state} mission", "bad_mission_state")


def mission_from_row(row: dict[str, Any]) -> Mission:
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
        robots=[MissionRobot.from_json(d) for d in progress.get("robots", [])],
        coverage=stored_coverage(row["plan"], row["params"], progress),
        reason=row["reason"],
        started_at=row["started_at"],
        ended_at=row["ended_at"],
        run_s=row["run_s"],
        owner=row.get("owner"),
        requested=row.get("requested"),
        run_id=progress.get("run_id"),
        rehearsal=progress.get("rehearsal"),
    )
    if m.state == "running":  # a mirror counts its running time from the last save
        m.running_since = row["updated_at"]
    return m


def pause_robots(m: Mission) -> None:
    """Robots that were under way when their replica stopped: stopped, to carry on from there on Resume."""
    for r in m.robots:
        if r.status in ("moving", "waiting", "pending"):
            r.status, r.command_id = "paused", None
