"""Stepping a coverage or waypoints mission: legs sent and watched, dropouts and re-plans, robots holding
their place, critical alarms pausing a robot, robots too close warned about. Every step takes ``now``."""

from __future__ import annotations

import math
from functools import partial
from typing import Any

from backend.core.alarm_rules import OFFLINE_IN_MISSION
from backend.core.errors import ServiceError
from backend.schemas.commands import CommandCreate
from backend.services.control.args import CommandError
from backend.services.missions.book import (
    FAILED_COMMAND,
    LEG_TOLERANCE_M,
    SAVE_EVERY_S,
    SYSTEM,
    MissionBook,
    log,
    mm_below,
)
from backend.services.missions.record import Mission
from backend.services.missions.state import HOLD_DRIFT_M, HOLD_TOLERANCE_M, MissionRobot, hand_over, takeover_of

MAX_RETRIES = 3
#: a robot outside the mission closer than the minimum separation + this to one of its robots: a warning event
NEAR_MARGIN_M = 0.2
#: ... warned about again once it went this much further away first
NEAR_REARM_M = 0.1
#: positions older than this are not compared
NEAR_FIX_S = 2.0


class MissionStepping(MissionBook):
    async def _step_legs(self, m: Mission, now: float) -> None:
        """One step of a coverage or waypoints mission: legs done or failed, dropouts and re-plans, the next
        legs, robots holding their place, the end."""
        if m.coverage.deferred:  # read from its row (a restart, a takeover): its grid is built once, on the pool
            await self._coverage_ready(m, queued=True)
        for r in m.robots:
            if r.active:
                await self._alarm_pause(m, r, now)
        for r in m.robots:
            if not r.active:
                continue
            why, ended = self._observe(r), False
            if why is None and r.status == "moving" and r.command_id is not None:
                cmd = self._commands.cached(r.command_id)
                if cmd is None:
                    why = "its command was lost"
                elif cmd.status == "done":
                    r.index, r.status, r.command_id = r.leg_end, "pending", None
                elif cmd.status in FAILED_COMMAND:
                    why, ended = f"{cmd.status}: {cmd.reason}", True
                    if self._retry(m, r, cmd.status, cmd.reason, now):
                        why = None
            if why is not None:
                await self._drop(m, r, why, now, leg_ended=ended)
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
            m.coverage.update(m.robots)  # the points added since the last update only (state.Coverage)
            self._save(m, now)

    def _retry(self, m: Mission, r: MissionRobot, status: str, reason: str, now: float) -> bool:
        """A lost fix ends a leg, not the robot: the leg is sent again (a few times, a ``retry`` event each).
        Anything else (a lost link included: never resumed silently) drops the robot out."""
        retries = m.extra.setdefault("retries", {})
        # a leg refused because the robot has not heard this server's heartbeat or the fleet's poses yet (it just
        # started) never began; a blocked leg (failed: blocked) drops the robot, as a stalled one does
        waiting = reason.startswith(("unsupervised", "no_poses"))
        transient = reason.startswith("no_position") or (status == "rejected" and waiting)
        if not transient or retries.get(r.robot_id, 0) >= MAX_RETRIES:
            return False
        retries[r.robot_id] = retries.get(r.robot_id, 0) + 1
        r.index = max(r.index, min(r.reached, r.leg_end))
        r.status, r.command_id = "pending", None
        self._event(m, "retry", r.robot_id, {"reason": reason, "attempt": retries[r.robot_id]}, now)
        return True

    def _observe(self, r: MissionRobot) -> str | None:
        """Record where a mission robot is now; why it must drop out (offline, held by its stop latch), or None."""
        st = self._registry.get(r.robot_id)
        if st is not None and st.position is not None:
            r.observe(st.position.x, st.position.y)
        if st is None or not st.online:
            return "offline"
        if st.hold is not None:
            return f"held: {st.hold.reason or st.hold.source}"
        return None

    async def _next(self, m: Mission, r: MissionRobot, now: float) -> None:
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
                    detail = {"near": rid, "distance_m": mm_below(d), "limit_m": round(limit, 3)}
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
                    self._event(m, "too_close", a, {"near": b, "distance_m": mm_below(d), "limit_m": sep}, now)
                    log.warning("mission %s: %s and %s %.2f m apart (minimum %.2f m)", m.id, a, b, d, sep)
                elif d > sep + NEAR_REARM_M:
                    close.pop(key, None)

    async def _hold(self, m: Mission, r: MissionRobot) -> None:
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

    async def _alarm_pause(self, m: Mission, r: MissionRobot, now: float) -> None:
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

    async def _drop(self, m: Mission, r: MissionRobot, why: str, now: float, *, leg_ended: bool = False) -> None:
        """A robot that failed, went offline or is held: its remaining area goes to the others at once. A robot
        whose leg ended by itself (failed, refused) has stopped already and gets no ``stop``: parked, it keeps
        clear of its neighbours (docs/autonomy.md), which a stop would end."""
        was_moving = r.status == "moving" and not leg_ended
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
        view = (await self._coverage_ready(m, queued=True)).view()
        overlap = float(m.params.get("overlap", 0.0))
        stopped = [x.robot_id for x in m.robots if x.status == "dropped"]
        clear = [(p.x, p.y) for rid in stopped if (st := self._registry.get(rid)) and st.online and (p := st.position)]
        sep = float(m.plan.get("min_separation_m", 0.3))
        plan = None
        if view is not None:  # the swept outline and the plan: both off the loop, handed over on it
            plan = await self.planner.run_queued(
                partial(takeover_of, view, r.polygon, len(survivors), overlap, sep, clear)
            )
        given = hand_over(r, survivors, plan)
        self._event(m, "replan", r.robot_id, {"to": [x.robot_id for x in survivors][:given], "parts": given}, now)

    def _online(self, robot_id: str) -> bool:
        return (st := self._registry.get(robot_id)) is not None and st.online and st.hold is None
