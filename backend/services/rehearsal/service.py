"""Rehearsals on the live server: the mission, the site and where its robots are now, handed to a process of
its own (the twin is CPU work: in the server's process the GIL would slow the event loop), one rehearsal at a
time per client, a few in all; the prediction kept with the mission (the run it starts records it)."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import copy
import itertools
import logging
import math
import multiprocessing
import os
import secrets
import statistics
import time
from typing import Any

from backend.core.errors import ServiceError
from backend.services.fleet.registry import Registry, RobotState
from backend.services.missions.record import Mission
from backend.services.missions.service import MissionService
from backend.services.rehearsal.twin import MAX_SIM_S, RehearsalInput, RobotStart, rehearse
from backend.services.site.service import SiteService

log = logging.getLogger(__name__)

#: rehearsals running at once in the whole server (each a process, one core)
MAX_RUNNING = 2
#: seeds one request may ask for
MAX_SEEDS = 5
#: the figures a spread is given for
SPREAD_OF = ("duration_s", "covered_fraction", "min_separation_m", "filter_interventions", "blocked_legs")
#: the simulated time a rehearsal may run: its longest path at SLOW_MPS, or its ``duration_s``, and this more
SLOW_MPS = 0.05
MARGIN_S = 60.0
#: robots of no mission whose fix is this fresh are in the twin, standing where they are
BYSTANDER_FIX_S = 10.0


def _lower_priority() -> None:
    """A rehearsal yields to the server on a busy machine (the live fleet comes first)."""
    with contextlib.suppress(OSError):
        os.nice(10)


def time_limit(m: Mission) -> float:
    """How long a rehearsal of ``m`` may run (simulated): a robot at :data:`SLOW_MPS` on the longest path, or
    a formation's ``duration_s``, plus :data:`MARGIN_S`; at most the twin's ``MAX_SIM_S``."""
    if m.params.get("duration_s"):
        need = float(m.params["duration_s"])
    else:
        need = max((path_length(r.path) for r in m.robots), default=0.0) / SLOW_MPS
    return min(MAX_SIM_S, need + MARGIN_S)


def robot_start(st: RobotState, in_mission: bool) -> RobotStart | None:
    """Where a robot is (its latest fix, to 0.1 mm: as the mission keeps it, so that a repeat starts from
    exactly there) and what its agent published of its kinematics; None without a fix."""
    pos = st.position
    if pos is None:
        return None
    settings = (st.config or {}).get("config") or {}
    speed, base = settings.get("max_speed_mps"), settings.get("wheel_base_m")
    kinematics = settings.get("kinematics")
    return RobotStart(
        st.id,
        round(pos.x, 4),
        round(pos.y, 4),
        round(pos.yaw or 0.0, 4),
        max_speed_mps=float(speed) if isinstance(speed, int | float) and 0 < speed <= 10 else 0.3,
        wheel_base_m=float(base) if isinstance(base, int | float) and 0 < base <= 5 else 0.2,
        kinematics=kinematics if isinstance(kinematics, dict) else None,
        in_mission=in_mission,
        filtered=st.collision_filter and not st.legacy,
    )


def _last_starts(m: Mission) -> list[RobotStart]:
    """Where the robots were for the mission's latest rehearsal (409 when it has none)."""
    start = (m.rehearsal or {}).get("start")
    if not isinstance(start, dict) or set(start) != set(m.robot_ids):
        raise ServiceError(
            409, "the mission has no rehearsal of its robots to repeat: rehearse it first", "no_rehearsal"
        )
    out = []
    for rid in m.robot_ids:
        x, y, yaw = (float(v) for v in start[rid][:3])
        out.append(RobotStart(rid, x, y, yaw))
    return out


def path_length(path: list[list[float]]) -> float:
    return sum(math.dist(a, b) for a, b in itertools.pairwise(path))


def rehearse_seeds(inp: RehearsalInput, seeds: list[int]) -> list[dict[str, Any]]:
    """In the rehearsal's process: one twin run per seed."""
    return [rehearse(copy.deepcopy(inp), seed) for seed in seeds]


class RehearsalService:
    def __init__(self, *, missions: MissionService, registry: Registry, site: SiteService) -> None:
        self._missions = missions
        self._registry = registry
        self._site = site
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        self._clients: set[str] = set()

    def _executor(self) -> concurrent.futures.ProcessPoolExecutor:
        if self._pool is None:  # spawned, not forked: the server has threads (fork would copy their locks)
            self._pool = concurrent.futures.ProcessPoolExecutor(
                max_workers=MAX_RUNNING, mp_context=multiprocessing.get_context("spawn"), initializer=_lower_priority
            )
        return self._pool

    def snapshot(self, mission_id: str, from_last: bool = False, limit_s: float | None = None) -> RehearsalInput:
        """The mission as it is, the current site and each of its robots' latest fix (``from_last``: where they
        were for the mission's latest rehearsal, to repeat it exactly): what the twin starts from."""
        m = self._missions.get(mission_id)
        if m.state not in ("draft", "paused"):
            raise ServiceError(
                409,
                f"a {m.state} mission cannot be rehearsed (a draft, or a paused one before its resume)",
                "bad_mission_state",
            )
        limit_s = time_limit(m) if limit_s is None else limit_s
        current = self._site.current
        if current is None or current.site is None:
            raise ServiceError(409, "no site is set: a rehearsal runs inside the site", "no_site")
        if from_last:
            return RehearsalInput(copy.deepcopy(m), current.message().model_dump(mode="json"), _last_starts(m), limit_s)
        starts, missing = [], []
        for rid in m.robot_ids:
            st = self._registry.get(rid)
            start = None if st is None else robot_start(st, in_mission=True)
            if start is None:
                missing.append(rid)
            else:
                starts.append(start)
        if missing:
            raise ServiceError(
                422,
                f"no position fix yet for {', '.join(missing)}: the twin starts from where each robot is",
                "no_position",
            )
        now = time.time()
        for st in self._registry.robots.values():  # the others in the water: neighbours standing where they are
            pos = st.position
            if st.id not in m.robot_ids and st.online and pos is not None and now - pos.ts <= BYSTANDER_FIX_S:
                bystander = robot_start(st, in_mission=False)
                if bystander is not None:
                    starts.append(bystander)
        return RehearsalInput(copy.deepcopy(m), current.message().model_dump(mode="json"), starts, limit_s)

    async def rehearse(
        self, mission_id: str, client: str, seeds: int, seed: int | None, from_last: bool = False
    ) -> dict[str, Any]:
        """The prediction of ``seeds`` twin runs (the first with ``seed``, or a random one; each next one +1),
        from where the robots are now or (``from_last``) where they were for the latest rehearsal."""
        if client in self._clients:
            raise ServiceError(429, "a rehearsal of yours is running: one at a time", "rehearsal_running")
        if len(self._clients) >= MAX_RUNNING:
            raise ServiceError(503, f"{MAX_RUNNING} rehearsals are running: try again shortly", "rehearsals_busy")
        inp = self.snapshot(mission_id, from_last)
        first = secrets.randbelow(2**31) if seed is None else seed
        chosen = [first + i for i in range(seeds)]
        self._clients.add(client)
        try:
            future = self._executor().submit(rehearse_seeds, inp, chosen)
            runs: list[dict[str, Any]] = await asyncio.wrap_future(future)
        finally:
            self._clients.discard(client)
        result = summarise(runs)
        result["start"] = {r.robot_id: [r.x, r.y, r.yaw] for r in inp.robots if r.in_mission}
        kept = {k: v for k, v in result.items() if k not in ("predicted", "runs")}
        kept["predicted"] = {k: v for k, v in result["predicted"].items() if k != "tracks"}
        kept["at"] = time.time()
        m = self._missions.missions.get(mission_id)
        if m is not None and m.state in ("draft", "paused"):  # the run it starts records it
            self._missions.keep_rehearsal(mission_id, kept)
        return result

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The first run's prediction, its speed, and with several seeds the spread of each figure."""
    first = runs[0]
    took = sum(r["took_s"] for r in runs)
    simulated = sum(r["predicted"]["duration_s"] for r in runs)
    out: dict[str, Any] = {
        "predicted": first["predicted"],
        "seed": first["seed"],
        "seeds": [r["seed"] for r in runs],
        "speed_factor": round(simulated / took, 1) if took > 0 else None,
        "took_s": round(took, 3),
    }
    if len(runs) > 1:
        spread: dict[str, dict[str, float] | None] = {}
        for key in SPREAD_OF:
            values = [r["predicted"][key] for r in runs if r["predicted"][key] is not None]
            spread[key] = (
                {"min": min(values), "median": statistics.median(values), "max": max(values)} if values else None
            )
        out["spread"] = spread
        out["runs"] = [
            {"seed": r["seed"], "predicted": {k: v for k, v in r["predicted"].items() if k != "tracks"}} for r in runs
        ]
    return out
