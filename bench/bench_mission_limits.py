"""Missions at the edges of their schema (issue 28: a clumsy number never stalls the control plane).

A real Mosquitto and ``fleet-server`` (SQLite, the default 4 m x 4 m pool site), 20 robots known to it (their
status published as their agents do: a draft mission needs no more). Each mission kind (coverage, waypoints,
formation) is posted with each numeric field of its schema at the field's minimum and at its maximum (the
others at their defaults; a bound that is exclusive, ``> 0``, is met by the smallest number above it), then
with every field at its minimum at once and every field at its maximum at once. Printed: each answer's
status, code and time; the event loop's longest lag over the run and its stalls over 0.1 s and 0.2 s
(``/api/stats``, from the server's loop watchdog); and the longest ``/api/health`` answer of a client polling
it all along (20 ms apart). Targets: every answer within 1 s, no stall of 0.2 s or more.

    .venv/bin/python bench/bench_mission_limits.py [--quick]
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx
import orjson

from bench.common import report, stack
from fleet_protocol import MAX_COORDINATE_M, MAX_PATH_WAYPOINTS, MAX_POLYGON_POINTS, Topics
from tests.support.mqtt import MqttProbe
from tests.support.procs import wait_for

ROBOTS = [f"lim-{i}" for i in range(20)]
#: the smallest number above 0 (an exclusive minimum), the largest below 0.9 (overlap's exclusive maximum)
TINY = math.nextafter(0.0, 1.0)
BELOW_09 = math.nextafter(0.9, 0.0)
FAR = MAX_COORDINATE_M


def _zigzag(n: int, y0: float = 0.0) -> list[list[float]]:
    """``n`` points inside the pool's fence (x in [-1.5, 1.5]), a hair apart where there are many."""
    return [[-1.5 + 3.0 * i / max(1, n - 1), y0 + (0.02 if i % 2 else 0.0)] for i in range(n)]


def _circle(n: int, r: float = 1.5) -> list[list[float]]:
    return [[r * math.cos(2 * math.pi * i / n), r * math.sin(2 * math.pi * i / n)] for i in range(n)]


def _far_square() -> list[list[float]]:
    return [[-FAR, -FAR], [FAR, -FAR], [FAR, FAR], [-FAR, FAR]]


def coverage(robots: int = 2, **params: Any) -> dict[str, Any]:
    return {"type": "coverage", "robots": ROBOTS[:robots], "params": params}


def waypoints(robots: int = 2, points: int = 3, **params: Any) -> dict[str, Any]:
    paths = {rid: _zigzag(points, -1.5 + 3.0 * i / max(1, robots - 1)) for i, rid in enumerate(ROBOTS[:robots])}
    return {"type": "waypoints", "robots": ROBOTS[:robots], "params": {"paths": paths, **params}}


def formation(robots: int = 3, points: int = 4, slots: dict[str, list[float]] | None = None, **params: Any) -> dict:
    leader, followers = ROBOTS[0], ROBOTS[1:robots]
    grid = {rid: [-0.4 * (1 + i // 5), -1.0 + 0.5 * (i % 5)] for i, rid in enumerate(followers)}  # 0.4 m apart
    return {
        "type": "formation",
        "robots": ROBOTS[:robots],
        "params": {"leader": leader, "path": _zigzag(points), "slots": slots or grid, **params},
    }


def cases(quick: bool) -> list[tuple[str, dict[str, Any]]]:
    """(name, body): each numeric field at its minimum and maximum, then all at once."""
    corners = _circle(MAX_POLYGON_POINTS)
    edge_slots = {ROBOTS[1]: [-3.0, -3.0], ROBOTS[2]: [3.0, 3.0]}
    everything = [
        ("coverage: every field at its minimum", coverage(1, sweep_width_m=TINY, overlap=0.0, speed=TINY)),
        (
            "coverage: every field at its maximum",
            coverage(20, sweep_width_m=2.0, overlap=BELOW_09, speed=1.0, area=corners),
        ),
        ("waypoints: every field at its minimum", waypoints(1, 1, speed=TINY)),
        # 20 paths of 500 points are more than a request body may hold (FLEET_MAX_BODY_BYTES, 64 KB): 413
        ("waypoints: every field at its maximum", waypoints(20, MAX_PATH_WAYPOINTS, speed=1.0)),
        ("formation: every field at its minimum", formation(2, 2, speed=TINY, duration_s=TINY)),
        ("formation: every field at its maximum", formation(20, MAX_PATH_WAYPOINTS, speed=0.15, duration_s=86400.0)),
    ]
    if quick:
        return [
            ("coverage: sweep_width_m 10 um (issue 28)", coverage(sweep_width_m=1e-5)),
            ("coverage: sweep_width_m min", coverage(sweep_width_m=TINY)),
            *everything,
        ]
    return [
        ("coverage: sweep_width_m 10 um (issue 28)", coverage(sweep_width_m=1e-5)),
        ("coverage: sweep_width_m min", coverage(sweep_width_m=TINY)),
        ("coverage: sweep_width_m max", coverage(sweep_width_m=2.0)),
        ("coverage: overlap min", coverage(overlap=0.0)),
        ("coverage: overlap max", coverage(overlap=BELOW_09)),
        ("coverage: speed min", coverage(speed=TINY)),
        ("coverage: speed max", coverage(speed=1.0)),
        ("coverage: robots min", coverage(1)),
        ("coverage: robots max", coverage(20)),
        ("coverage: area corners max", coverage(area=corners)),
        ("coverage: area coordinates at +-max", coverage(area=_far_square())),
        ("waypoints: points min", waypoints(points=1)),
        ("waypoints: points max", waypoints(points=MAX_PATH_WAYPOINTS)),
        ("waypoints: robots max", waypoints(20)),
        ("waypoints: coordinates at +-max", {**waypoints(1), "params": {"paths": {ROBOTS[0]: [[-FAR, FAR]]}}}),
        ("waypoints: speed min", waypoints(speed=TINY)),
        ("waypoints: speed max", waypoints(speed=1.0)),
        ("formation: path points min", formation(points=2)),
        ("formation: path points max", formation(points=MAX_PATH_WAYPOINTS)),
        ("formation: robots max", formation(20)),
        ("formation: slot offsets at +-max", formation(slots=edge_slots)),
        ("formation: speed min", formation(speed=TINY)),
        ("formation: speed max", formation(speed=0.15)),
        ("formation: duration_s min", formation(duration_s=TINY)),
        ("formation: duration_s max", formation(duration_s=86400.0)),
        *everything,
    ]


def announce(probe: MqttProbe, topics: Topics, online: bool) -> None:
    """Each robot's status as its agent would publish it (retained): the server knows them, online or not."""
    for rid in ROBOTS:
        status = {"online": online, "ts": time.time(), "agent_version": "bench", "capabilities": {"sensors": []}}
        probe.publish(topics.status(rid), orjson.dumps(status), retain=True)


def wide_site() -> dict[str, Any]:
    """The largest site a request can set (``PUT /api/site``: 200 corners a polygon, 20 keep-outs, a body of
    64 KB at most): a 2 km pool of 200 corners with 20 keep-outs of 100 corners each, to the millimetre."""

    def ring(cx: float, cy: float, r: float, n: int) -> list[list[float]]:
        return [[round(cx + x, 3), round(cy + y, 3)] for x, y in _circle(n, r)]

    keepouts = [ring(-500.0 + 200.0 * (i % 5), -400.0 + 200.0 * (i // 5), 30.0, 100) for i in range(20)]
    return {"boundary": ring(0.0, 0.0, 999.0, 200), "keepouts": keepouts}


SQUARE_300 = [[0.0, 0.0], [300.0, 0.0], [300.0, 300.0], [0.0, 300.0]]
WIDE_CASES = [
    ("wide site: coverage, 20 robots, sweep_width_m max", coverage(20, sweep_width_m=2.0)),
    ("wide site: coverage, 1 robot, sweep_width_m max", coverage(1, sweep_width_m=2.0)),
    ("wide site: coverage, 20 robots, a 300 m square", coverage(20, sweep_width_m=2.0, area=SQUARE_300)),
]


def post(c: httpx.Client, name: str, body: dict[str, Any]) -> dict[str, Any]:
    """One mission posted: its answer's status, code and time (a draft made is aborted: nothing is left)."""
    t0 = time.perf_counter()
    r = c.post("/api/missions", json=body)
    took = time.perf_counter() - t0
    if r.status_code == 201:
        c.post(f"/api/missions/{r.json()['id']}/abort")
    code = r.json().get("code", "") if r.status_code >= 400 else ""
    return {"case": name, "status": r.status_code, "code": code, "s": took}


class HealthPoller:
    """``/api/health`` every 20 ms on a thread of its own: the longest answer while the missions are posted."""

    def __init__(self, client_factory: Any) -> None:
        self._client_factory = client_factory
        self._stop = threading.Event()
        self.longest_s = 0.0
        self.answers = 0
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with self._client_factory() as c:
            while True:  # asked at once, then every 20 ms until the posts are done
                t0 = time.perf_counter()
                c.get("/api/health")
                self.longest_s = max(self.longest_s, time.perf_counter() - t0)
                self.answers += 1
                if self._stop.wait(0.02):
                    return

    def __enter__(self) -> HealthPoller:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="the issue's width, sweep_width_m's minimum, all-at-once")
    args = p.parse_args()
    topics = Topics()
    answers: list[dict[str, Any]] = []
    with stack() as (broker, server, _work):
        probe = MqttProbe(broker.host, broker.port)
        try:
            announce(probe, topics, online=True)
            with server.client() as c:
                known = lambda: set(ROBOTS) <= {r["id"] for r in c.get("/api/robots").json()}  # noqa: E731
                wait_for(known, 30, what="the robots known")
                loop_before = c.get("/api/stats").json()["event_loop"]
                with HealthPoller(server.client) as health:
                    for name, body in cases(args.quick):
                        answers.append(post(c, name, body))
                    if not args.quick:  # then the widest site a request can set, and plans over it
                        site = c.put("/api/site", json=wide_site())
                        assert site.status_code == 200, site.text
                        for name, body in WIDE_CASES:
                            answers.append(post(c, name, body))
                loop = c.get("/api/stats").json()["event_loop"]
            announce(probe, topics, online=False)  # gone: the stack's cleanup forgets them
        finally:
            probe.close()
    slowest = max(a["s"] for a in answers)
    stalls_01 = loop["stalls"] - loop_before["stalls"]
    stalls_02 = loop["alarmed_stalls"] - loop_before["alarmed_stalls"]
    rows = [
        (a["case"], f"{a['s'] * 1000:.0f} ms", f"{a['status']} {a['code']}".strip(), "yes" if a["s"] <= 1 else "NO")
        for a in answers
    ]
    rows += [
        ("slowest answer", f"{slowest * 1000:.0f} ms", "<= 1000 ms", "yes" if slowest <= 1 else "NO"),
        ("loop: longest lag over the run", f"{loop['max_lag_ms']:.0f} ms", "< 200 ms", ""),
        ("loop: stalls > 0.1 s while posting", str(stalls_01), "", ""),
        ("loop: stalls >= 0.2 s while posting", str(stalls_02), "0", "yes" if stalls_02 == 0 else "NO"),
        ("/api/health: longest answer", f"{health.longest_s * 1000:.0f} ms", f"({health.answers} asked)", ""),
    ]
    report(
        "mission limits",
        rows,
        {
            "cases": len(answers),
            "slowest_s": slowest,
            "answers": {a["case"]: {"status": a["status"], "code": a["code"], "s": a["s"]} for a in answers},
            "loop_max_lag_ms": loop["max_lag_ms"],
            "loop_max_lag_before_ms": loop_before["max_lag_ms"],
            "stalls_over_100ms": stalls_01,
            "stalls_over_200ms": stalls_02,
            "health_longest_s": health.longest_s,
            "health_answers": health.answers,
        },
    )


if __name__ == "__main__":
    main()
