"""Stepping a formation mission: the slow half (the leader's path, dropouts, the end) and starting the fast
half, the FormationDriver that drives the followers (formation.py)."""

from __future__ import annotations

from typing import Any

from backend.core.errors import ServiceError
from backend.schemas.commands import CommandCreate
from backend.services.control.args import CommandError
from backend.services.missions.book import FAILED_COMMAND, LEG_TOLERANCE_M, SAVE_EVERY_S, SYSTEM
from backend.services.missions.formation import DRIVE_DEADMAN_S, FormationDriver
from backend.services.missions.record import Mission
from backend.services.missions.state import MissionRobot
from backend.services.missions.stepping import MissionStepping


class FormationStepping(MissionStepping):
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

    async def _send_leader_path(self, m: Mission, leader: MissionRobot, now: float) -> None:
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

        driver = FormationDriver(
            leader=form["leader"], slots=slots, registry=self._registry, send=send, clock=self._clock
        )
        self._formations[m.id] = driver
        driver.start(f"formation-{m.id}")
