"""Gap repair: how many messages the broker dropped for a frozen server, and how long their repair took.

A real Mosquitto whose queue per client holds ``--queue`` messages, the real server (its in-flight window
``--receive-maximum``, so the broker holds at most queue + window for it) and ``--robots`` simulated agents
publishing position at ``--rate`` Hz. The server is frozen (SIGSTOP) for ``--freeze`` seconds, then
resumed. Measured: messages repaired, seconds from SIGCONT until every stream has no open gap, the
slowest stream's repair (from the gap's detection to its last repaired message, the server's
``telemetry_repaired`` events), messages lost, and whether the database then holds every seq once.

    .venv/bin/python bench/bench_gap_repair.py [--robots 3] [--rate 100] [--freeze 5] [--queue 200]
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx
from sqlalchemy import create_engine, text

from bench.common import report
from tests.support.procs import AgentProcess, Broker, ServerProcess, wait_for


def streams(c: httpx.Client, robots: list[str]) -> dict[tuple[str, str], dict[str, object]]:
    out = {}
    for rid in robots:
        for s in c.get(f"/api/robots/{rid}/streams").json():
            out[(rid, s["stream"])] = s
    return out


def stored_exactly_once(database_url: str) -> bool:
    engine = create_engine(database_url)
    try:
        with engine.connect() as conn:
            rows = conn.execute(
                text(
                    "SELECT robot_id, stream, count(*), count(DISTINCT seq), min(seq), max(seq) "
                    "FROM telemetry GROUP BY robot_id, stream"
                )
            ).all()
    finally:
        engine.dispose()
    return bool(rows) and all(n == distinct == hi - lo + 1 and lo == 0 for _r, _s, n, distinct, lo, hi in rows)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=3)
    p.add_argument("--rate", type=float, default=100.0, help="position Hz per robot")
    p.add_argument("--freeze", type=float, default=5.0, help="seconds the server is frozen")
    p.add_argument("--queue", type=int, default=200, help="Mosquitto max_queued_messages")
    p.add_argument("--receive-maximum", type=int, default=100, help="the server's MQTT v5 in-flight window")
    args = p.parse_args()
    robots = [f"bench-gap-{i}" for i in range(args.robots)]
    with tempfile.TemporaryDirectory(prefix="fleet-bench-") as tmp:
        work = Path(tmp)
        broker = Broker(work)
        broker.conf.write_text(
            broker.conf.read_text().replace("max_queued_messages 100000", f"max_queued_messages {args.queue}")
        )
        broker.start()
        database_url = f"sqlite:///{work / 'fleet.db'}"
        server = ServerProcess(
            broker, database_url, work, FLEET_AUTH="off", FLEET_MQTT_RECEIVE_MAXIMUM=str(args.receive_maximum)
        )
        agents = [AgentProcess(rid, broker, work, ["--position-rate", str(args.rate)]) for rid in robots]
        try:
            server.start()
            for a in agents:
                a.start()
            with httpx.Client(base_url=server.base_url, timeout=15) as c:
                wait_for(
                    lambda: (
                        all(
                            int(s.get("count", 0)) > args.rate
                            for k, s in streams(c, robots).items()
                            if k[1] == "position"
                        )
                        and len(streams(c, robots)) >= 2 * args.robots
                    ),
                    60,
                    what="agents streaming",
                )
                assert server.proc is not None
                os.kill(server.proc.pid, signal.SIGSTOP)
                time.sleep(args.freeze)  # the bench's setting: how long the server is away
                os.kill(server.proc.pid, signal.SIGCONT)
                resumed = time.monotonic()

                def clean() -> dict[tuple[str, str], dict[str, object]] | None:
                    s = streams(c, robots)
                    done = all(v["gaps_open"] == 0 for v in s.values()) and all(
                        int(s[(rid, "position")]["gaps_repaired"]) > 0 for rid in robots
                    )  # type: ignore[call-overload]
                    return s if done else None

                final = wait_for(
                    clean,
                    120,
                    interval=0.1,
                    what="every gap repaired (none: the broker held it all? a smaller --queue)",
                )
                took = time.monotonic() - resumed
                repaired_streams = sum(1 for v in final.values() if int(v["gaps_repaired"]))  # type: ignore[call-overload]

                def repaired_events() -> list[dict[str, Any]] | None:  # (written by the server a moment later)
                    ev = c.get("/api/events", params={"kind": "telemetry_repaired", "limit": 1000}).json()
                    return ev if len(ev) >= repaired_streams else None

                events = wait_for(repaired_events, 30, what="the telemetry_repaired events")
            for a in agents:
                a.stop()
            exact = wait_for(lambda: stored_exactly_once(database_url), 60, interval=0.5, what="rows settled")
        finally:
            for a in agents:
                a.stop()
            server.stop()
            broker.stop()
    repaired = sum(int(v["gaps_repaired"]) for v in final.values())  # type: ignore[call-overload]
    lost = sum(int(v["gaps_lost"]) for v in final.values())  # type: ignore[call-overload]
    slowest = max((float(e["detail"]["seconds"]) for e in events), default=float("nan"))
    setting = (
        f"{args.robots} robots x {args.rate:g} Hz, server frozen {args.freeze:g} s, queue {args.queue}, "
        f"receive maximum {args.receive_maximum}"
    )
    report(
        f"gap repair ({setting})",
        [
            ("messages repaired", str(repaired), "> 0", "yes" if repaired > 0 else "NO"),
            ("messages lost", str(lost), "0", "yes" if lost == 0 else "NO"),
            ("SIGCONT -> no open gap (s)", f"{took:.2f}", "<= 15", "yes" if took <= 15 else "NO"),
            ("slowest stream: gap seen -> repaired (s)", f"{slowest:.2f}", "", ""),
            ("database: every seq 0..N once", str(exact), "True", "yes" if exact else "NO"),
        ],
        {
            "robots": args.robots,
            "rate_hz": args.rate,
            "freeze_s": args.freeze,
            "queue": args.queue,
            "receive_maximum": args.receive_maximum,
            "repaired": repaired,
            "lost": lost,
            "clean_after_s": round(took, 3),
            "slowest_stream_s": round(slowest, 3),
            "exactly_once": bool(exact),
        },
    )


if __name__ == "__main__":
    main()
