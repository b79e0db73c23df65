"""Helpers of the mission tests: the retained site (published by the test until the server's site service
does it), ready robots, stored tracks and the measures taken on them (min separation, coverage fill)."""

from __future__ import annotations

import itertools
import math
import time
from typing import Any

import httpx
import numpy as np
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.ops import unary_union
from shapely.prepared import prep

from fleet_protocol import QOS_SITE, AvoidanceSettings, Site, SiteMessage, Topics, default_pool_site, dumps, now
from tests.support.mqtt import MqttProbe
from tests.support.procs import wait_for

T = Topics()


def publish_site(probe: MqttProbe, avoidance: AvoidanceSettings | None = None) -> None:
    """The simulator's pool, retained: the agents refuse goals until they have a site. Without ``avoidance``
    (as an older server) the robots run without the safety filter; the server's own site carries it."""
    msg = SiteMessage(version=1, site=default_pool_site(), ts=now(), avoidance=avoidance)
    probe.publish(T.site(), dumps(msg), qos=QOS_SITE, retain=True)


def server_site_without_filter(c: httpx.Client) -> None:
    """The server's own site (the simulator's pool) with the robots' safety filter off, set through the API:
    the server publishes it after its own first copy, so no race decides which one the robots keep (a test's
    site published beside a server that had just connected was overwritten once by the server's)."""
    body = default_pool_site().model_dump(mode="json") | {"avoidance": {"enabled": False}}
    r = c.put("/api/site", json=body)
    assert r.status_code == 200, r.text


def wait_ready(c: httpx.Client, robots: list[str], timeout: float = 40.0) -> None:
    def ready() -> bool:
        got = {r["id"]: r for r in c.get("/api/robots").json()}
        return all(rid in got and got[rid]["ready"] for rid in robots)

    wait_for(ready, timeout, interval=0.3, what=f"{robots} ready")


def wait_state(c: httpx.Client, mission_id: str, states: tuple[str, ...], timeout: float) -> dict[str, Any]:
    box: dict[str, Any] = {}

    def reached() -> bool:
        box["m"] = c.get(f"/api/missions/{mission_id}").json()
        return box["m"]["state"] in states

    wait_for(reached, timeout, interval=0.5, what=f"mission in {states}")
    return box["m"]


def stored_stream(c: httpx.Client, robot_id: str, stream: str, start: float, end: float) -> list[dict[str, Any]]:
    """Every stored point (``{"ts", "data"}``) of one of the robot's streams in [start, end], via the API."""
    out: list[dict[str, Any]] = []
    cursor = None
    while True:
        params: dict[str, Any] = {"stream": stream, "start": start, "end": end, "raw": "true", "limit": 10000}
        if cursor:
            params["cursor"] = cursor
        r = c.get(f"/api/robots/{robot_id}/telemetry", params=params)
        assert r.status_code == 200, r.text
        page = r.json()
        out += page["points"]
        cursor = page.get("next_cursor")
        if not cursor:
            return out


def stored_track(c: httpx.Client, robot_id: str, start: float, end: float) -> list[tuple[float, float, float]]:
    """(ts, x, y) of every stored position of the robot in [start, end], from the database via the API."""
    return [(p["ts"], p["data"]["x"], p["data"]["y"]) for p in stored_stream(c, robot_id, "position", start, end)]


def closest_approach(
    tracks: dict[str, list[tuple[float, float, float]]], window_s: float = 0.15
) -> tuple[float, float, str, str]:
    """(distance, ts, robot a, robot b) of the moment two robots were closest, centre to centre: each stored fix
    of one robot against the other's fixes around it in time (within ``window_s``), linearly interpolated."""
    worst: tuple[float, float, str, str] = (math.inf, math.nan, "", "")
    for a, b in itertools.combinations(tracks, 2):
        tb = tracks[b]
        j = 0
        for ts, x, y in tracks[a]:
            while j + 1 < len(tb) and tb[j + 1][0] <= ts:
                j += 1
            if j + 1 >= len(tb) or not (tb[j][0] <= ts <= tb[j + 1][0]) or tb[j + 1][0] - tb[j][0] > window_s:
                continue
            (t0, x0, y0), (t1, x1, y1) = tb[j], tb[j + 1]
            f = 0.0 if t1 == t0 else (ts - t0) / (t1 - t0)
            d = math.hypot(x - (x0 + f * (x1 - x0)), y - (y0 + f * (y1 - y0)))
            if d < worst[0]:
                worst = (d, ts, a, b)
    return worst


def min_pairwise_distance(tracks: dict[str, list[tuple[float, float, float]]], window_s: float = 0.15) -> float:
    """Smallest centre-to-centre distance between two robots at the same moment (:func:`closest_approach`)."""
    return closest_approach(tracks, window_s)[0]


def _strip(pts: list[tuple[float, float, float]], width: float) -> BaseGeometry:
    xy = [(x, y) for _, x, y in pts]
    if not xy:
        return Polygon()
    return LineString(xy).buffer(width / 2) if len(xy) > 1 else Point(xy[0]).buffer(width / 2)


def coverage_fill(tracks: dict[str, list[tuple[float, float, float]]], area: BaseGeometry, width: float) -> float:
    """Share of ``area`` swept by the tracks (each buffered by half the sweep width), all robots together."""
    strips = [_strip(pts, width) for pts in tracks.values()]
    return float(unary_union(strips).intersection(area).area / area.area)


def swept_by_robot(
    tracks: dict[str, list[tuple[float, float, float]]], area: BaseGeometry, width: float
) -> dict[str, float]:
    """m² of ``area`` each robot's own track swept (a robot's work; overlaps with others count for both)."""
    return {rid: float(_strip(pts, width).intersection(area).area) for rid, pts in tracks.items()}


def safe_region(site: Site) -> BaseGeometry:
    """Where the robots' own geofence lets goals be: the boundary shrunk by the margin, minus the keep-outs grown
    by it (robot_agent/motion/geofence.py)."""
    region = Polygon(site.boundary).buffer(-site.geofence_margin_m)
    for k in site.keepouts:
        region = region.difference(Polygon(k).buffer(site.geofence_margin_m))
    return region


def fence_crossings(tracks: dict[str, list[tuple[float, float, float]]], site: Site) -> int:
    """Times a stored track went from inside the safe region to outside it (a robot starting outside counts)."""
    region = prep(safe_region(site))
    crossings = 0
    for pts in tracks.values():
        inside = True
        for _, x, y in pts:
            now_inside = region.covers(Point(x, y))
            crossings += inside and not now_inside
            inside = now_inside
    return crossings


def path_turns(path: list[list[float]], min_deg: float = 10.0) -> list[float]:
    """The turning angles (radians) at the corners of a polyline, those above ``min_deg``."""
    out = []
    for a, b, c in zip(path, path[1:], path[2:], strict=False):
        h1, h2 = math.atan2(b[1] - a[1], b[0] - a[0]), math.atan2(c[1] - b[1], c[0] - b[0])
        if math.dist(a, b) < 1e-9 or math.dist(b, c) < 1e-9:
            continue
        turn = abs((h2 - h1 + math.pi) % (2 * math.pi) - math.pi)
        if turn >= math.radians(min_deg):
            out.append(turn)
    return out


def settle(seconds: float) -> None:
    time.sleep(seconds)


def lawn_track(x0: float, x1: float, y0: float, y1: float, spacing: float, seed: int = 0) -> list[list[float]]:
    """A robot's track as a mission stores it: a point every 2 cm (state.TRACK_STEP_M) along lanes of constant
    x, ``spacing`` apart, swept up and down, with a centimetre of noise across (the current)."""
    rng = np.random.default_rng(seed)
    track: list[list[float]] = []
    for i, x in enumerate(np.arange(x0, x1, spacing)):
        ys = np.arange(y0, y1, 0.02)
        for y in ys[::-1] if i % 2 else ys:
            track.append([round(float(x + rng.normal(0, 0.01)), 4), round(float(y), 4)])
    return track
