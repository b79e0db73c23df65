"""Run export: time and peak memory to write a run as MCAP (and Parquet) from a stored database.

A fresh SQLite database gets ``--robots`` x ``--rate`` Hz x ``--minutes`` of position rows (bulk SQL, not
through the server: 10 x 50 Hz x 10 min = 300,000 rows) and ``--frames`` camera JPEGs in a frame store,
then the exporter the server streams from (backend/services/runs/export.py) writes the run into a file
that only counts bytes. Issue 19's target: 300,000 rows + 3,000 frames as MCAP in <= 15 s.

    .venv/bin/python bench/bench_runs_export.py [--robots 10 --rate 50 --minutes 10 --frames 3000]
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import report

FILL = r"""
WITH RECURSIVE s(i) AS (SELECT 0 UNION ALL SELECT i + 1 FROM s WHERE i < :n - 1)
INSERT INTO telemetry (robot_id, stream, ts, seq, x, y, z, yaw, payload)
SELECT :robot, 'position', :t0 + i * :dt, i, x, y, 0.0, yaw,
       '{"x":' || x || ',"y":' || y || ',"z"\:0.0,"yaw":' || yaw || '}'
FROM (SELECT i, ((i * 7919) % 4000) / 1000.0 - 2.0 AS x, ((i * 104729) % 4000) / 1000.0 - 2.0 AS y,
             (i % 628) / 100.0 - 3.14 AS yaw FROM s)
"""


class CountingSink:
    def __init__(self) -> None:
        self.n = 0

    def write(self, data: Any) -> int:
        self.n += len(data)
        return len(data)

    def tell(self) -> int:
        return self.n

    def flush(self) -> None:
        pass


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--rate", type=float, default=50.0)
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--frames", type=int, default=3000)
    p.add_argument("--frame-kb", type=int, default=30)
    args = p.parse_args()

    from sqlalchemy import text

    from backend.core.config import Settings
    from backend.services.runs.export import RunExport, write_mcap, write_parquet_zip
    from backend.services.runs.frames import FrameStore
    from backend.store.db import create_db_engine, upgrade_to_head

    with tempfile.TemporaryDirectory(prefix="bench-runs-") as tmp:
        work = Path(tmp)
        engine = create_db_engine(Settings(database_url=f"sqlite:///{work / 'fleet.db'}"))
        upgrade_to_head(engine)
        t0 = 1_800_000_000.0
        per_robot = int(args.rate * args.minutes * 60)
        robots = [f"bench-{i}" for i in range(args.robots)]
        with engine.begin() as conn:
            for rid in robots:
                conn.execute(text(FILL), {"robot": rid, "n": per_robot, "t0": t0, "dt": 1 / args.rate})
        end = t0 + args.minutes * 60
        frames = FrameStore(root=work / "runs", quota_bytes=1 << 40)
        jpeg = b"\xff\xd8" + bytes(args.frame_kb * 1024) + b"\xff\xd9"
        for k in range(args.frames):
            rid = robots[k % len(robots)]
            d = work / "runs" / "1" / rid
            d.mkdir(parents=True, exist_ok=True)
            (d / f"{round((t0 + k * (end - t0) / args.frames) * 1e9):019d}_{k}.jpg").write_bytes(jpeg)
        run = {
            "id": 1,
            "name": "bench",
            "notes": "",
            "tags": [],
            "operator": "bench",
            "robots": robots,
            "started_at": t0,
            "ended_at": end,
            "site_version": "",
            "agents": {},
            "frame_rate": 5.0,
        }
        export = RunExport(engine=engine, frames=frames, run=run, markers=[], summary={}, site={}, end=end)
        rows = per_robot * len(robots)

        start = time.perf_counter()
        mcap = CountingSink()
        counts = write_mcap(export, mcap)  # type: ignore[arg-type]
        mcap_s = time.perf_counter() - start
        start = time.perf_counter()
        pq = CountingSink()
        write_parquet_zip(export, pq)  # type: ignore[arg-type]
        parquet_s = time.perf_counter() - start
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        engine.dispose()

    report(
        "runs-export",
        [
            (
                f"MCAP, {rows:,} rows + {args.frames:,} frames",
                f"{mcap_s:.1f} s",
                "<= 15 s",
                "yes" if mcap_s <= 15 else "NO",
            ),
            ("MCAP size", f"{mcap.n / 1e6:.1f} MB", "", ""),
            (f"Parquet, {rows:,} rows", f"{parquet_s:.1f} s", "", ""),
            ("Parquet size", f"{pq.n / 1e6:.1f} MB", "", ""),
            ("peak RSS of the process", f"{peak_mb:.0f} MB", "", ""),
        ],
        {
            "rows": rows,
            "frames": args.frames,
            "mcap_messages": sum(counts.values()),
            "mcap_s": mcap_s,
            "parquet_s": parquet_s,
            "peak_rss_mb": peak_mb,
        },
    )


if __name__ == "__main__":
    main()
