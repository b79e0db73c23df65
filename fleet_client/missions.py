"""Missions from a script: create (with its plan), start, pause, resume, abort, read, wait, and the swept area
(GeoJSON or PNG). Part of :class:`~fleet_client.FleetClient`; docs/missions.md explains missions.

    m = fleet.create_mission(["r1", "r2"], area=[[-1, -1], [1, -1], [1, 1], [-1, 1]], sweep_width_m=0.2)
    fleet.start_mission(m["id"])
    done = fleet.wait_mission(m["id"])               # the mission once completed; MissionFailed otherwise
    fleet.mission_coverage_png(m["id"], "swept.png")
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import httpx

from fleet_client.errors import MissionFailed

#: states after which a mission never changes again
MISSION_ENDED = frozenset({"completed", "aborted", "failed"})
DEFAULT_MISSION_WAIT_S = 3600.0
#: a rehearsal of the longest mission takes about a minute on one core (the twin runs an hour at 50 x)
REHEARSAL_TIMEOUT_S = 180.0


class MissionsMixin:
    """Methods of :class:`fleet_client.FleetClient` for missions (docs/missions.md)."""

    if TYPE_CHECKING:
        _http: httpx.Client

        def _request(self, method: str, path: str, ok: tuple[int, ...] = (200,), **kw: Any) -> httpx.Response: ...

        def _download(self, path: str, params: dict[str, Any], out: str | Path | IO[bytes]) -> dict[str, str]: ...

    def create_mission(
        self,
        robots: Sequence[str],
        *,
        type: str = "coverage",
        name: str = "",
        area: Sequence[Sequence[float]] | None = None,
        sweep_width_m: float | None = None,
        overlap: float | None = None,
        speed: float | None = None,
        paths: Mapping[str, Sequence[Sequence[float]]] | None = None,
    ) -> dict[str, Any]:
        """A draft mission with its plan (``parts``: each robot's polygon and path); nothing moves until
        :meth:`start_mission`. Coverage: ``area`` (default the whole site), ``sweep_width_m``, ``overlap``,
        ``speed``. Waypoints (``type="waypoints"``): ``paths`` {robot: [[x, y], ...]}. Bad input raises
        FleetError 422 whose ``code`` says what (unknown_robot, bad_area, area_outside_site ...) and whose
        detail names the field."""
        params: dict[str, Any] = {"speed": speed}
        if type == "waypoints":
            params["paths"] = {rid: [[float(x), float(y)] for x, y in pts] for rid, pts in (paths or {}).items()}
        else:
            params.update(sweep_width_m=sweep_width_m, overlap=overlap)
            if area is not None:
                params["area"] = [[float(p[0]), float(p[1])] for p in area]
        body = {"type": type, "name": name, "robots": list(robots), "params": _without_none(params)}
        return self._request("POST", "/api/missions", ok=(201,), json=body).json()

    def start_mission(self, mission_id: str) -> dict[str, Any]:
        """draft -> running; every robot must be ready (else 422 robot_not_ready with the reasons)."""
        return self._action(mission_id, "start", None)

    def pause_mission(self, mission_id: str, reason: str = "") -> dict[str, Any]:
        """running -> paused: the robots stop (motors off)."""
        return self._action(mission_id, "pause", {"reason": reason})

    def resume_mission(self, mission_id: str, rejoin: Sequence[str] = ()) -> dict[str, Any]:
        """paused -> running, each robot from where it is; ``rejoin`` names dropped robots to take back."""
        return self._action(mission_id, "resume", {"rejoin": list(rejoin)})

    def abort_mission(self, mission_id: str, reason: str = "") -> dict[str, Any]:
        """draft, running or paused -> aborted: the robots stop. Final."""
        return self._action(mission_id, "abort", {"reason": reason})

    def rehearse_mission(
        self,
        mission_id: str,
        seeds: int = 1,
        seed: int | None = None,
        again: bool = False,
        timeout: float = REHEARSAL_TIMEOUT_S,
    ) -> dict[str, Any]:
        """Run a draft (or paused) mission in the server's simulated twin of the fleet, from where its robots
        are now, and return what it predicts: ``predicted`` (``duration_s``, ``covered_fraction``,
        ``min_separation_m``, ``fence_violations``, ``collisions``, ``filter_interventions``, ``blocked_legs``,
        ``per_robot``, ``tracks`` as GeoJSON), ``seed``, ``speed_factor``, ``took_s``; with ``seeds`` > 1 (at
        most 5) also ``spread``; ``start``, where each robot started. The same ``seed`` from the same start gives
        the same prediction: ``again`` starts from where the latest rehearsal did (docs/missions.md, Rehearsal)."""
        params: dict[str, Any] = {"seeds": seeds, "start": "last" if again else "now"}
        if seed is not None:
            params["seed"] = seed
        path = f"/api/missions/{mission_id}/rehearsal"
        return self._request("POST", path, params=params, timeout=timeout).json()

    def missions(self) -> list[dict[str, Any]]:
        """Every mission (summary), newest first."""
        return self._request("GET", "/api/missions").json()

    def mission(self, mission_id: str) -> dict[str, Any]:
        """State, per-robot progress, covered fraction, elapsed time, ETA, plan, transitions and events."""
        return self._request("GET", f"/api/missions/{mission_id}").json()

    def mission_coverage(self, mission_id: str) -> dict[str, Any]:
        """The area the robots' tracks swept, a GeoJSON geometry (shapely: ``shape(...)``)."""
        return self._request("GET", f"/api/missions/{mission_id}/coverage", params={"format": "geojson"}).json()

    def mission_coverage_png(
        self, mission_id: str, out: str | Path | IO[bytes], px_per_m: float = 100.0
    ) -> dict[str, str]:
        """The swept area as a PNG into ``out`` (a path or a binary file): swept green, workable but unswept
        grey, outside transparent. Returns the X-Fleet-* headers: ``x-fleet-bounds`` (minx,miny,maxx,maxy in
        metres; the picture's top row is maxy), ``x-fleet-resolution-m``, ``x-fleet-covered-fraction``."""
        return self._download(f"/api/missions/{mission_id}/coverage", {"format": "png", "px_per_m": px_per_m}, out)

    def wait_mission(
        self,
        mission_id: str,
        timeout: float = DEFAULT_MISSION_WAIT_S,
        interval: float = 0.5,
        until: Sequence[str] = ("completed",),
    ) -> dict[str, Any]:
        """Wait until the mission reaches a state of ``until`` (default: completed) and return it. A mission
        that ends otherwise (aborted, failed), or is still elsewhere after ``timeout`` seconds, raises
        :class:`MissionFailed` (``state``: its state, or ``timeout``). A paused mission is waited on: an
        operator may resume it (pass ``until=("completed", "paused")`` to stop there)."""
        deadline = time.monotonic() + timeout
        while True:
            m = self.mission(mission_id)
            if m["state"] in until:
                return m
            if m["state"] in MISSION_ENDED:
                raise MissionFailed(m)
            if time.monotonic() >= deadline:
                raise MissionFailed(m, timed_out=timeout)
            time.sleep(interval)

    def _action(self, mission_id: str, action: str, body: dict[str, Any] | None) -> dict[str, Any]:
        return self._request("POST", f"/api/missions/{mission_id}/{action}", json=body).json()


def _without_none(d: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in d.items() if v is not None}
