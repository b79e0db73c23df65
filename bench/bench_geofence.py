"""The geofence under attack: robots driven at the fence over and over, every simulator disturbance on (the
water current included), several robots in parallel.

Each attempt, in turn: a held seed ``move_forward`` at full speed, a held ``drive`` at the speed limit (both
renewed every 100 ms for 5 s, as the dashboard does), a ``goto`` beyond the fence and a ``follow_path``
through it. Before a driven attempt the robot goes to a point 0.55 m inside a random side of the fence,
facing it up to 40 degrees off square. Measured on the robots' own position streams: how close any robot
came to the fence while driven (the issue: never across it, over 200 attempts).

    .venv/bin/python bench/bench_geofence.py [--robots 5] [--attempts 40]
"""

from __future__ import annotations

import argparse
import math
import random
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import report
from fleet_protocol import Site
from tests.support.motion import FakeServer
from tests.support.procs import AgentProcess, Broker

HALF = 1.2  # the fence: a square inside the pool (the simulator's walls would stop a robot at 1.9 m anyway)
FENCE = Site(boundary=[[-HALF, -HALF], [HALF, -HALF], [HALF, HALF], [-HALF, HALF]], geofence_margin_m=0.15)


def inside_margin(x: float, y: float) -> float:
    """Distance to the fence (negative: across it)."""
    return HALF - max(abs(x), abs(y))


def attack(srv: FakeServer, rid: str, attempts: int, seed: int, out: dict[str, Any]) -> None:
    rng = random.Random(seed)
    windows, refused, stopped, kinds = [], 0, 0, {"move_forward": 0, "drive": 0, "goto": 0, "follow_path": 0}
    for n in range(attempts):
        kind = ("move_forward", "drive", "goto", "follow_path")[n % 4]
        kinds[kind] += 1
        side = rng.uniform(-math.pi, math.pi)
        reach = (HALF + 0.1) / max(abs(math.cos(side)), abs(math.sin(side)))  # 10 cm beyond the fence
        target = (reach * math.cos(side), reach * math.sin(side))
        if kind in ("goto", "follow_path"):
            args: dict[str, Any] = (
                {"x": target[0], "y": target[1]} if kind == "goto" else {"waypoints": [[0.0, 0.0], list(target)]}
            )
            if srv.final_ack(rid, srv.send(rid, kind, args), 10)["status"] == "rejected":
                refused += 1
            continue
        # 0.55 m inside one side of the fence, heading at it up to 40 degrees off square
        turn = rng.choice((0.0, math.pi / 2, math.pi, -math.pi / 2))
        bx, by, off = HALF - 0.55, rng.uniform(-0.6, 0.6), rng.uniform(-0.7, 0.7)
        sx, sy = bx * math.cos(turn) - by * math.sin(turn), bx * math.sin(turn) + by * math.cos(turn)
        yaw = turn + off
        back = srv.send(rid, "goto", {"x": sx, "y": sy, "yaw": yaw, "tolerance_m": 0.08})
        srv.final_ack(rid, back, 90)
        args = {"speed": 1.0, "duration_s": 0.35} if kind == "move_forward" else {"linear": 1.0, "duration_s": 0.35}
        t0, ids = time.time(), []
        for k in range(50):
            ids.append(srv.send(rid, kind, args))
            time.sleep(max(0.0, t0 + 0.1 * (k + 1) - time.time()))  # the dashboard's renewal rate
        finals = [srv.final_ack(rid, i, 10) for i in ids]
        windows.append((t0, finals[-1]["ts"] + 0.5))
        stopped += any("geofence" in f["reason"] for f in finals)
    closest = math.inf
    for t0, t1 in windows:
        for e in srv.stream(rid, "position", since=t0):
            if e["ts"] <= t1:
                closest = min(closest, inside_margin(e["data"]["x"], e["data"]["y"]))
    out[rid] = {
        "attempts": attempts,
        "driven": len(windows),
        "stopped": stopped,
        "refused": refused,
        "closest_m": closest,
        "kinds": kinds,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=5)
    p.add_argument("--attempts", type=int, default=40, help="per robot")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="fleet-bench-fence-") as tmp:
        work = Path(tmp)
        broker = Broker(work)
        broker.start()
        srv = FakeServer(broker.host, broker.port)
        agents: list[AgentProcess] = []
        results: dict[str, Any] = {}
        try:
            srv.publish_site(1, FENCE)
            srv.start_heartbeat()
            ids = [f"bench-f{i + 1}" for i in range(args.robots)]
            for i, rid in enumerate(ids):
                agents.append(AgentProcess(rid, broker, work, ["--disturbances", f"--start-pose=0,{0.1 * i:.1f},0"]))
                agents[-1].start()
            for rid in ids:
                srv.wait_online(rid, timeout=60)
            t0 = time.monotonic()
            threads = [
                threading.Thread(target=attack, args=(srv, rid, args.attempts, i, results)) for i, rid in enumerate(ids)
            ]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            wall = time.monotonic() - t0
        finally:
            for a in agents:
                a.stop()
            srv.close()
            broker.stop()
    total = sum(r["attempts"] for r in results.values())
    driven = sum(r["driven"] for r in results.values())
    stopped = sum(r["stopped"] for r in results.values())
    refused = sum(r["refused"] for r in results.values())
    closest = min((r["closest_m"] for r in results.values()), default=math.nan)
    rows = [
        ("attempts (robots x attempts)", f"{total} ({args.robots}x{args.attempts})", "200", ""),
        ("driven at the fence for 5 s (held move_forward / drive)", f"{driven}", "", ""),
        ("  of which stopped by the geofence", f"{stopped}", f"{driven}", "yes" if stopped == driven else "NO"),
        (
            "goals / paths beyond the fence refused",
            f"{refused} of {total - driven}",
            f"{total - driven}",
            "yes" if refused == total - driven else "NO",
        ),
        (
            "closest approach to the fence while driven",
            f"{closest * 100:.1f} cm",
            "> 0 (never across)",
            "yes" if closest > 0 else "NO",
        ),
        ("wall time", f"{wall:.0f} s", "", ""),
    ]
    report(
        "geofence",
        rows,
        {
            "attempts": total,
            "driven": driven,
            "stopped": stopped,
            "refused": refused,
            "closest_m": closest,
            "wall_s": wall,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
