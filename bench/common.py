"""Shared bench plumbing: the real stack (Mosquitto + fleet-server) on free ports, process RSS/CPU from
/proc, percentiles, and the result format ``run_all.py`` collects (a table, then one JSON line)."""

from __future__ import annotations

import contextlib
import json
import os
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.support.procs import Broker, ServerProcess  # noqa: E402  (after the path fix)

RESULT_PREFIX = "RESULT "


def percentile(values: Sequence[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    k = min(len(s) - 1, max(0, round(q / 100 * (len(s) - 1))))
    return s[k]


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks  # utime + stime


def forget_robots(server: ServerProcess, offline_within_s: float = 5.0) -> None:
    """Clean up after a bench: the server forgets every robot it created (DELETE /api/robots/{id}), so none
    is left in a database that outlives the run (``--database postgres`` against a shared server, a demo).
    Robots still online after ``offline_within_s`` are left and named. Never fails the bench."""
    import time

    try:
        with server.client() as http:
            deadline = time.monotonic() + offline_within_s
            robots = http.get("/api/robots").json()
            while any(r["online"] for r in robots) and time.monotonic() < deadline:
                time.sleep(0.2)
                robots = http.get("/api/robots").json()
            left = []
            for r in robots:
                # telemetry is kept: the run's database is thrown away with it, and deleting is slow
                if http.delete(f"/api/robots/{r['id']}", params={"telemetry": "keep"}).status_code != 200:
                    left.append(r["id"])
    except Exception as exc:  # cleanup is best effort
        print(f"cleanup: could not forget the bench robots: {exc}", file=sys.stderr)
        return
    print(
        f"cleanup: {len(robots) - len(left)} robots forgotten" + (f", left (online): {left}" if left else ""),
        file=sys.stderr,
    )


@contextlib.contextmanager
def stack(**server_env: str) -> Iterator[tuple[Broker, ServerProcess, Path]]:
    """Mosquitto (queues large enough for the load) and the server with a fresh SQLite database."""
    with tempfile.TemporaryDirectory(prefix="fleet-bench-") as tmp:
        work = Path(tmp)
        broker = Broker(work, extra_conf="max_queued_messages 1000000\n")
        broker.start()
        server = ServerProcess(broker, f"sqlite:///{work / 'fleet.db'}", work, **server_env)
        try:
            server.start()
            yield broker, server, work
            forget_robots(server)
        finally:
            server.stop()
            broker.stop()


def report(name: str, rows: list[tuple[str, str, str, str]], result: dict[str, Any]) -> None:
    """Print ``what | measured | target | ok`` rows, then the machine-readable line."""
    width = max(len(r[0]) for r in rows) if rows else 10
    print(f"\n{name}")
    print(f"{'what':<{width}}  {'measured':>14}  {'target':>14}  ok")
    for what, measured, target, ok in rows:
        print(f"{what:<{width}}  {measured:>14}  {target:>14}  {ok}")
    print(RESULT_PREFIX + json.dumps({"bench": name, **result}, default=float))
