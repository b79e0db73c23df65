"""History: time to answer a 2,000-point query over 1 million and 10 million stored rows.

For each database (SQLite, PostgreSQL) and each ``--rows`` N, a fresh database gets N position rows of one
robot (50 Hz, built with bulk SQL, not through the server) and the rollup the server's job keeps current
(per-second and per-minute aggregates; its time is reported too). Then a real server answers over HTTP:
the whole range in ``--points`` points (N rows: 55 hours at 10 M), a one-hour window of the same robot
(180,000 rows), and a raw CSV export of 100,000 rows (streamed). Each query runs once cold, then
``--repeat`` times (median reported).

    .venv/bin/python bench/bench_history.py [--rows 1000000 --rows 10000000] [--database sqlite|postgres|both]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_ingest import database
from bench.common import report
from tests.support.procs import Broker, ServerProcess

ROBOT = "hist-0"
RATE_HZ = 50.0

SQLITE_FILL = r"""
WITH RECURSIVE s(i) AS (SELECT :lo UNION ALL SELECT i + 1 FROM s WHERE i < :hi - 1)
INSERT INTO telemetry (robot_id, stream, ts, seq, x, y, z, yaw, payload)
SELECT :robot, 'position', :t0 + i * :dt, i, x, y, 0.0, yaw,
       '{"x":' || x || ',"y":' || y || ',"z"\:0.0,"yaw":' || yaw || '}'
FROM (SELECT i, ((i * 7919) % 4000) / 1000.0 - 2.0 AS x, ((i * 104729) % 4000) / 1000.0 - 2.0 AS y,
             (i % 628) / 100.0 - 3.14 AS yaw FROM s)
"""

PG_FILL = r"""
INSERT INTO telemetry (robot_id, stream, ts, seq, x, y, z, yaw, payload)
SELECT :robot, 'position', :t0 + i * :dt, i, x, y, 0.0, yaw,
       format('{"x":%s,"y":%s,"z"\:0.0,"yaw":%s}', x, y, yaw)
FROM (SELECT i, ((i * 7919) % 4000) / 1000.0 - 2.0 AS x, ((i * 104729) % 4000) / 1000.0 - 2.0 AS y,
             (i % 628) / 100.0 - 3.14 AS yaw FROM generate_series(CAST(:lo AS BIGINT), CAST(:hi AS BIGINT) - 1) AS i) s
"""


def build(url: str, rows: int, t0: float) -> tuple[float, float]:
    """Schema via the migrations, ``rows`` rows by bulk SQL, then the rollup the server's job would have done
    meanwhile (every minute marked dirty, rolled up). Returns (load seconds, rollup seconds)."""
    from sqlalchemy import text

    from backend.core.config import Settings
    from backend.store.db import create_db_engine, upgrade_to_head
    from backend.store.rollup import mark_all_dirty, run_rollup

    engine = create_db_engine(Settings(database_url=url))
    try:
        upgrade_to_head(engine)
        sql = PG_FILL if engine.dialect.name == "postgresql" else SQLITE_FILL
        start = time.perf_counter()
        chunk = 1_000_000
        for lo in range(0, rows, chunk):
            with engine.begin() as conn:
                conn.execute(
                    text(sql), {"robot": ROBOT, "t0": t0, "dt": 1 / RATE_HZ, "lo": lo, "hi": min(rows, lo + chunk)}
                )
        with engine.begin() as conn:
            conn.execute(
                text(
                    "INSERT INTO robots (id, legacy, agent_version, capabilities, first_seen, last_seen, online) "
                    "VALUES (:r, false, 'bench', '{}', :t0, :t0, false)"
                ),
                {"r": ROBOT, "t0": t0},
            )
            conn.execute(text("ANALYZE"))
        load_s = time.perf_counter() - start
        start = time.perf_counter()
        mark_all_dirty(engine)
        run_rollup(engine, time.time())
        with engine.begin() as conn:
            conn.execute(text("ANALYZE"))
        return load_s, time.perf_counter() - start
    finally:
        engine.dispose()


def timed(c: httpx.Client, params: dict[str, Any], repeat: int) -> tuple[float, float, int, str]:
    """(cold s, warm median s, points, method)"""

    def once() -> tuple[float, httpx.Response]:
        t = time.perf_counter()
        r = c.get(f"/api/robots/{ROBOT}/telemetry", params=params)
        r.raise_for_status()
        return time.perf_counter() - t, r

    cold, r = once()
    warm = [once()[0] for _ in range(repeat)]
    if params.get("format") == "csv":
        rows = sum(1 for line in r.content.splitlines() if not line.startswith(b"#")) - 1  # minus the header
        return cold, statistics.median(warm), rows, r.headers["x-fleet-method"]
    body = r.json()
    return cold, statistics.median(warm), len(body["points"]), body["method"]


def run_one(kind: str, rows: int, points: int, repeat: int) -> dict[str, Any]:
    t0 = time.time() - rows / RATE_HZ - 3600
    with tempfile.TemporaryDirectory(prefix="fleet-bench-history-") as tmp:
        work = Path(tmp)
        with database(kind, work) as url:
            build_s, rollup_s = build(url, rows, t0)
            broker = Broker(work)
            broker.start()
            server = ServerProcess(broker, url, work, FLEET_RETENTION_RAW_DAYS="0", FLEET_RETENTION_AGG_DAYS="0")
            try:
                server.start()
                with server.client() as c:
                    c.timeout = 300
                    full = timed(c, {"max_points": points}, repeat)
                    mid = t0 + rows / RATE_HZ / 2
                    hour = timed(c, {"max_points": points, "start": mid, "end": mid + 3600}, repeat)
                    export_rows = min(rows, 100_000)
                    export = timed(c, {"raw": "true", "format": "csv", "limit": export_rows}, max(1, repeat // 2))
            finally:
                server.stop()
                broker.stop()
    return {
        "database": kind,
        "rows": rows,
        "points": points,
        "build_s": build_s,
        "build_rows_s": rows / build_s,
        "rollup_s": rollup_s,
        "rollup_rows_s": rows / rollup_s,
        "full_cold_s": full[0],
        "full_warm_s": full[1],
        "full_points": full[2],
        "full_method": full[3],
        "hour_cold_s": hour[0],
        "hour_warm_s": hour[1],
        "hour_points": hour[2],
        "export_rows": export[2],
        "export_s": export[1],
        "export_rows_s": export[2] / export[1],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rows", type=int, action="append", help="rows stored (repeatable); default 1e6 and 1e7")
    p.add_argument("--database", choices=["sqlite", "postgres", "both"], default="both")
    p.add_argument("--points", type=int, default=2000)
    p.add_argument("--repeat", type=int, default=5)
    args = p.parse_args()
    sizes = args.rows or [1_000_000, 10_000_000]
    kinds = ["sqlite", "postgres"] if args.database == "both" else [args.database]
    results = [run_one(k, n, args.points, args.repeat) for n in sizes for k in kinds]
    rows = []
    for r in results:
        tag = f"{r['database']} {r['rows']:,} rows"
        rows += [
            (f"{tag}: {r['points']}-pt query, whole range, warm (ms)", f"{r['full_warm_s'] * 1000:.0f}", "-", "-"),
            (f"{tag}: same, cold (ms)", f"{r['full_cold_s'] * 1000:.0f}", "-", "-"),
            (f"{tag}: {r['points']}-pt query, 1 h window (ms)", f"{r['hour_warm_s'] * 1000:.0f}", "-", "-"),
            (f"{tag}: raw CSV export (rows/s)", f"{r['export_rows_s']:.0f}", "-", "-"),
            (f"{tag}: bulk build (rows/s)", f"{r['build_rows_s']:.0f}", "-", "-"),
            (f"{tag}: rollup of all rows (rows/s)", f"{r['rollup_rows_s']:.0f}", "-", "-"),
        ]
    first = results[0]
    report("history", rows, {**first, "runs": results})


if __name__ == "__main__":
    main()
