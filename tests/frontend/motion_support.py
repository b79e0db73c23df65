"""Helpers for the dashboard's motion tests (issue 17): a robot that has the site (published retained by
the test, as the server will), its stored telemetry, and a gamepad emulated inside the page."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import Any

from fleet_protocol import QOS_SITE, SiteMessage, Topics, default_pool_site, dumps, now
from tests.backend.helpers import driveable, wait_robot
from tests.support.procs import AgentProcess, ServerProcess, wait_for

#: The stick's deadman (frontend/js/drive/velocity.js DEADMAN_S) and the project's stop bound (DEVELOPERS.md).
DEADMAN_S = 0.3
STOP_BOUND_S = 0.5

#: A gamepad the page sees through the Gamepad API: window.__pad.axes / .connected, set by the test.
GAMEPAD_INIT = """
window.__pad = { axes: [0, 0, 0, 0], connected: false };
const fakePad = () => ({ id: 'Test gamepad (emulated)', index: 0, connected: true, mapping: 'standard',
  timestamp: performance.now(), axes: window.__pad.axes.slice(),
  buttons: Array.from({ length: 16 }, () => ({ pressed: false, touched: false, value: 0 })) });
navigator.getGamepads = () => (window.__pad.connected ? [fakePad(), null, null, null] : [null, null, null, null]);
"""


def publish_site(probe_factory: Callable[..., Any], version: int = 1) -> None:
    """The simulator's pool as the retained site, before the agents start: they refuse goals without it."""
    probe = probe_factory()
    msg = SiteMessage(version=version, site=default_pool_site(), ts=now())
    probe.publish(Topics().site(), dumps(msg), qos=QOS_SITE, retain=True)


def start_robot(
    server: ServerProcess, spawn_agent: Callable[..., AgentProcess], rid: str, pose: str, *args: str
) -> AgentProcess:
    agent = spawn_agent(rid, f"--start-pose={pose}", *args)
    with server.client() as c:
        wait_robot(c, rid, driveable, timeout=30)
    return agent


def position(server: ServerProcess, rid: str) -> dict[str, Any]:
    with server.client() as c:
        return c.get(f"/api/robots/{rid}").json()["position"]  # type: ignore[no-any-return]


def stored(server: ServerProcess, rid: str, stream: str, start: float) -> list[dict[str, Any]]:
    """Every stored point of ``stream`` since ``start`` (raw, not bucketed)."""
    with server.client() as c:
        r = c.get(
            f"/api/robots/{rid}/telemetry",
            params={"stream": stream, "start": start, "raw": "true", "max_points": 10000},
        )
        assert r.status_code == 200, r.text
        return r.json()["points"]  # type: ignore[no-any-return]


def select(page: Any, rid: str) -> None:
    page.get_by_test_id(f"robot-row-{rid}").click()
    page.wait_for_function(f"() => window.fleetDebug.selected() === '{rid}'")


def moved_from(server: ServerProcess, rid: str, start: dict[str, Any], metres: float, timeout: float = 15) -> None:
    wait_for(
        lambda: math.hypot(position(server, rid)["x"] - start["x"], position(server, rid)["y"] - start["y"]) > metres,
        timeout,
        what=f"{rid} moved {metres} m",
    )


def drives_moving(server: ServerProcess, rid: str, start: float) -> list[dict[str, Any]]:
    """The robot's own ``motion`` reports of ``drive`` commands with turning wheels, since ``start``."""
    return [
        p
        for p in stored(server, rid, "motion", start)
        if p["data"]["mode"] == "drive" and (p["data"]["setpoint"]["left"] or p["data"]["setpoint"]["right"])
    ]


def stopped_after(server: ServerProcess, rid: str, released_at: float, event: str = "the stick was released") -> float:
    """Seconds from ``released_at`` (when ``event`` happened) to the first stored position sample after the
    robot's last movement (an upper bound of when it stopped). Waits until it has stood still for a second;
    the simulator runs with no water current, so a stopped robot stands still."""

    def still_for_a_second() -> list[float] | None:
        pts = stored(server, rid, "position", released_at - 1)
        moves = [
            q["ts"]
            for p, q in itertools.pairwise(pts)
            if math.hypot(q["data"]["x"] - p["data"]["x"], q["data"]["y"] - p["data"]["y"]) > 1e-4
        ]
        if not moves or pts[-1]["ts"] - moves[-1] < 1.0:
            return None
        return moves

    moves = wait_for(still_for_a_second, 15, interval=0.2, what=f"{rid} standing still")
    assert moves[0] < released_at, f"it was not moving when {event}: the test proves nothing"
    took = float(moves[-1] - released_at)
    print(f"{rid} stopped {took:.3f} s after {event}")
    return took
