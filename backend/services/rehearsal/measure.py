"""What a rehearsal predicts, measured on the simulator's truth (where the robots really are, not their noisy
fixes): the duration and coverage, the closest approach, contacts and fence violations, the safety filters'
interventions, blocked legs, each robot's distance and time, and the tracks as GeoJSON for the map."""

from __future__ import annotations

import itertools
import math
from typing import Any

import shapely
from shapely.geometry import Polygon

from backend.services.missions.record import Mission
from backend.services.rehearsal.robots import TwinClock, TwinRobot
from fleet_protocol import BODY_RADIUS_M, Site

#: a track point for the map every this many metres (the figures use every sample)
TRACK_STEP_M = 0.05
#: at most this many points per robot's track on the map (a long run's are thinned evenly)
MAX_TRACK_POINTS = 2000
#: robot states in which a robot's part of the mission is over
FINISHED = ("done", "dropped", "stopped")


class Measure:
    """Fed with :meth:`sample` every few tens of milliseconds of virtual time."""

    def __init__(self, site: Site, robots: dict[str, TwinRobot], clock: TwinClock, ours: list[str]) -> None:
        """``ours``: the mission's robots (the others are neighbours: a pair counts when one of it is ours)."""
        self._robots = robots
        self._clock = clock
        self._ours = set(ours)
        self._inside = Polygon(site.boundary)
        self._keepouts = [Polygon(k) for k in site.keepouts]
        for area in (self._inside, *self._keepouts):
            shapely.prepare(area)
        self.closest = math.inf
        self.closest_pair: tuple[str, str] | None = None
        self.contacts = 0
        self.fence_violations = 0
        self._touching: set[tuple[str, str]] = set()
        self._outside: set[str] = set()
        self.tracks: dict[str, list[tuple[float, float]]] = {rid: [] for rid in ours}
        self.distance: dict[str, float] = dict.fromkeys(ours, 0.0)
        self._last: dict[str, tuple[float, float]] = {}
        self.finished_at: dict[str, float] = {}

    def sample(self) -> None:
        here = {rid: robot.pose() for rid, robot in self._robots.items()}
        for rid, p in here.items():
            if rid not in self._ours:
                continue
            last = self._last.get(rid)
            if last is not None:
                self.distance[rid] += math.hypot(p.x - last[0], p.y - last[1])
            self._last[rid] = (p.x, p.y)
            track = self.tracks[rid]
            if not track or math.hypot(p.x - track[-1][0], p.y - track[-1][1]) >= TRACK_STEP_M:
                track.append((p.x, p.y))
            out = not shapely.contains_xy(self._inside, p.x, p.y) or any(
                shapely.contains_xy(k, p.x, p.y) for k in self._keepouts
            )
            if out and rid not in self._outside:
                self.fence_violations += 1
            (self._outside.add if out else self._outside.discard)(rid)
        for (a, pa), (b, pb) in itertools.combinations(sorted(here.items()), 2):
            if a not in self._ours and b not in self._ours:
                continue  # two robots of no mission: not the mission's doing
            d = math.hypot(pa.x - pb.x, pa.y - pb.y)
            if d < self.closest:
                self.closest, self.closest_pair = d, (a, b)
            touching = d < 2 * BODY_RADIUS_M
            if touching and (a, b) not in self._touching:
                self.contacts += 1
            (self._touching.add if touching else self._touching.discard)((a, b))

    def watch(self, mission: Mission, now: float) -> None:
        """When each robot's part ended (its time in the prediction)."""
        for r in mission.robots:
            if r.status in FINISHED and r.robot_id not in self.finished_at:
                self.finished_at[r.robot_id] = now

    def prediction(self, mission: Mission, events: list[dict[str, Any]], start: float, end: float) -> dict[str, Any]:
        if mission.type == "coverage" and not mission.coverage.deferred:
            mission.coverage.update(mission.robots)
        covered = round(mission.coverage.fraction, 4) if mission.type == "coverage" else None
        blocked = [
            e for e in events if e["kind"] in ("dropout", "retry") and "blocked" in str(e["detail"].get("reason", ""))
        ]
        logs = {rid: robot.filter_log for rid, robot in self._robots.items() if rid in self._ours}
        return {
            "duration_s": round(end - start, 2),
            "outcome": mission.state,
            "covered_fraction": covered,
            "min_separation_m": None if math.isinf(self.closest) else round(self.closest, 4),
            "closest_pair": list(self.closest_pair) if self.closest_pair else None,
            "fence_violations": self.fence_violations,
            "collisions": self.contacts,
            "filter_interventions": sum(log.interventions for log in logs.values()),
            "filter_seconds": round(sum(log.seconds for log in logs.values()), 2),
            "blocked_legs": len(blocked),
            "events": _event_counts(events),
            "per_robot": {
                rid: {
                    "distance_m": round(self.distance[rid], 3),
                    "duration_s": round(self.finished_at.get(rid, end) - start, 2),
                    "filter_interventions": logs[rid].interventions,
                    "status": next((r.status for r in mission.robots if r.robot_id == rid), None),
                }
                for rid in sorted(self._ours)
            },
            "tracks": self.geojson(),
        }

    def geojson(self) -> dict[str, Any]:
        features = []
        for rid, track in self.tracks.items():
            step = max(1, math.ceil(len(track) / MAX_TRACK_POINTS))
            points = track[::step] if len(track) > 1 else track * 2
            coords = [[round(x, 3), round(y, 3)] for x, y in points]
            if len(coords) < 2:
                continue
            features.append(
                {
                    "type": "Feature",
                    "properties": {"robot_id": rid},
                    "geometry": {"type": "LineString", "coordinates": coords},
                }
            )
        return {"type": "FeatureCollection", "features": features}


def _event_counts(events: list[dict[str, Any]]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for e in events:
        counts[e["kind"]] = counts.get(e["kind"], 0) + 1
    return counts
