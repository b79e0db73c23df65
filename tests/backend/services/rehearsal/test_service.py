"""The live server's side of rehearsals (backend/services/rehearsal/service.py), its process pool held: one
rehearsal at a time per client and a few in all, the refusals with their reasons, and the repeat of the latest
rehearsal from where it started. The twin itself: test_twin.py; with real parts: test_rehearsal_e2e.py."""

from __future__ import annotations

import asyncio
import concurrent.futures
import copy
import time
from typing import Any

import pytest

from backend.core.errors import ServiceError
from backend.services.missions.record import Mission
from backend.services.rehearsal import RehearsalService, RobotStart
from backend.services.rehearsal.server import TwinRegistry, TwinRobotState
from backend.services.site.service import SiteVersion
from fleet_protocol.motion import default_pool_site
from tests.support.rehearsal import draft

STARTS = [RobotStart("a", -0.5, -0.5, 0.0), RobotStart("b", 0.5, -0.5, 0.0)]
BODY = {"type": "coverage", "robots": ["a", "b"], "params": {"area": [[-1, -1], [1, -1], [1, 0], [-1, 0]]}}


class Missions:
    """The mission service's part a rehearsal uses."""

    def __init__(self, m: Mission) -> None:
        self.missions = {m.id: m}

    def get(self, mission_id: str) -> Mission:
        if mission_id not in self.missions:
            raise ServiceError(404, "unknown mission", "unknown_mission")
        return self.missions[mission_id]

    def keep_rehearsal(self, mission_id: str, rehearsal: dict[str, Any]) -> None:
        self.missions[mission_id].rehearsal = rehearsal


class Site:
    def __init__(self) -> None:
        self.current = SiteVersion(1, default_pool_site(), "test", "test", 0.0)


class HeldPool:
    """Submitted rehearsals wait until the test lets them finish."""

    def __init__(self) -> None:
        self.futures: list[concurrent.futures.Future[Any]] = []
        self.inputs: list[Any] = []

    def submit(self, fn: Any, inp: Any, seeds: list[int]) -> concurrent.futures.Future[Any]:
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        self.futures.append(future)
        self.inputs.append((inp, seeds))
        return future


DRAFT = draft(BODY, STARTS)


def _service(with_fixes: bool = True) -> tuple[RehearsalService, Missions, HeldPool]:
    m = copy.deepcopy(DRAFT)
    registry = TwinRegistry(["a", "b"])
    if with_fixes:
        for r in STARTS:
            registry.on_fix(r.robot_id, 0.0, {"x": r.x + 0.123456, "y": r.y, "yaw": r.yaw})
    missions = Missions(m)
    service = RehearsalService(missions=missions, registry=registry, site=Site())  # type: ignore[arg-type]
    pool = HeldPool()
    service._executor = lambda: pool  # type: ignore[assignment,return-value]
    return service, missions, pool


def _run(seed: int) -> dict[str, Any]:
    predicted = {
        "duration_s": 10.0 + seed,
        "covered_fraction": 0.9,
        "min_separation_m": 0.5,
        "filter_interventions": 0,
        "blocked_legs": 0,
        "tracks": {"type": "FeatureCollection", "features": []},
    }
    return {"predicted": predicted, "seed": seed, "took_s": 0.2}


async def _until(cond: Any) -> None:
    for _ in range(200):
        if cond():
            return
        await asyncio.sleep(0.005)
    raise AssertionError("condition never held")


def test_one_rehearsal_at_a_time_per_client_and_a_few_in_all() -> None:
    async def scenario() -> None:
        service, missions, pool = _service()
        mid = next(iter(missions.missions))
        alice = asyncio.create_task(service.rehearse(mid, "alice", 1, 3))
        await _until(lambda: len(pool.futures) == 1)
        with pytest.raises(ServiceError) as refused:
            await service.rehearse(mid, "alice", 1, 3)
        assert (refused.value.status_code, refused.value.code) == (429, "rehearsal_running")
        bob = asyncio.create_task(service.rehearse(mid, "bob", 2, 5))
        await _until(lambda: len(pool.futures) == 2)
        with pytest.raises(ServiceError) as busy:
            await service.rehearse(mid, "carol", 1, 3)
        assert (busy.value.status_code, busy.value.code) == (503, "rehearsals_busy")
        pool.futures[0].set_result([_run(3)])
        pool.futures[1].set_result([_run(5), _run(6)])
        first, second = await alice, await bob
        assert first["seed"] == 3 and "spread" not in first
        assert second["seeds"] == [5, 6] and second["spread"]["duration_s"] == {
            "min": 15.0,
            "median": 15.5,
            "max": 16.0,
        }
        # the mission keeps the latest, without its tracks, with where the robots started (to 0.1 mm)
        kept = missions.missions[mid].rehearsal
        assert kept is not None and kept["seed"] == 5 and "tracks" not in kept["predicted"]
        assert kept["start"]["a"] == [round(-0.5 + 0.123456, 4), -0.5, 0.0]
        # alice is free again, and repeats bob's from exactly where it started
        again = asyncio.create_task(service.rehearse(mid, "alice", 1, 5, from_last=True))
        await _until(lambda: len(pool.futures) == 3)
        inp, seeds = pool.inputs[2]
        assert seeds == [5] and [(r.x, r.y) for r in inp.robots] == [(-0.3765, -0.5), (0.6235, -0.5)]
        pool.futures[2].set_result([_run(5)])
        await again

    asyncio.run(scenario())


def test_refusals_say_why() -> None:
    async def scenario() -> None:
        service, missions, _ = _service(with_fixes=False)
        mid = next(iter(missions.missions))
        cases = [
            (dict(mission_id="nope"), 404, "unknown_mission"),
            (dict(mission_id=mid), 422, "no_position"),
            (dict(mission_id=mid, from_last=True), 409, "no_rehearsal"),
        ]
        for kwargs, status, code in cases:
            with pytest.raises(ServiceError) as refused:
                await service.rehearse(client="alice", seeds=1, seed=None, **kwargs)  # type: ignore[arg-type]
            assert (refused.value.status_code, refused.value.code) == (status, code), refused.value
        missions.missions[mid].state = "running"
        with pytest.raises(ServiceError) as running:
            await service.rehearse(mid, "alice", 1, None)
        assert (running.value.status_code, running.value.code) == (409, "bad_mission_state")
        assert not service._clients  # a refusal holds nothing

    asyncio.run(scenario())


def test_the_twin_starts_from_each_robots_kinematics_and_the_robots_around_the_mission() -> None:
    service, missions, _ = _service()
    registry = service._registry
    a = registry.get("a")
    assert a is not None
    a.config = {"config": {"max_speed_mps": 0.25, "wheel_base_m": 0.18, "kinematics": {"max_linear_mps": 0.1}}}
    registry.robots["old"] = TwinRobotState("old", legacy=True, collision_filter=False)
    registry.robots["idle"] = TwinRobotState("idle")
    registry.robots["gone"] = TwinRobotState("gone", online=False)
    for rid in ("old", "idle", "gone"):
        registry.on_fix(rid, time.time(), {"x": 1.5, "y": 1.5, "yaw": 0.0})
    registry.robots["stale"] = TwinRobotState("stale")
    registry.on_fix("stale", time.time() - 60, {"x": 1.0, "y": 1.0, "yaw": 0.0})
    inp = service.snapshot(next(iter(missions.missions)))
    starts = {r.robot_id: r for r in inp.robots}
    assert set(starts) == {"a", "b", "old", "idle"}  # offline, and a fix a minute old: not in the water
    assert (starts["a"].max_speed_mps, starts["a"].wheel_base_m) == (0.25, 0.18)
    assert starts["a"].kinematics == {"max_linear_mps": 0.1} and starts["b"].kinematics is None
    assert starts["a"].in_mission and not starts["idle"].in_mission and starts["idle"].filtered
    assert not starts["old"].in_mission and not starts["old"].filtered
