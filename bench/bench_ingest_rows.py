"""Ingest's row path in one process: CPU per telemetry row as the server stores it (the row built as
``TelemetryIngest`` builds it, then the writer's batch commit: the SQLite insert and the dirty-minute marks).

``bench_ingest.py`` measures the whole server against a broker, which on a shared machine swings with
everything else running; this measures the part that a change to the row or the insert touches
(``recv_ts``, a column) as process CPU time, which a busy machine disturbs far less.

    .venv/bin/python bench/bench_ingest_rows.py [--rows 120000] [--batch 1000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from backend.core.config import Settings
from backend.services.telemetry.ingest import telemetry_row
from backend.store.db import create_db_engine, upgrade_to_head
from backend.store.telemetry_inserts import TelemetryCommitter
from bench.common import report


def run_once(rows: int, batch: int) -> float:
    """CPU microseconds per row (build + commit) over ``rows`` position rows from 60 robots."""
    with tempfile.TemporaryDirectory() as d:
        engine = create_db_engine(Settings(database_url=f"sqlite:///{d}/bench.db"))
        upgrade_to_head(engine)
        committer = TelemetryCommitter(engine)  # the writer thread's commit, run here in this thread
        t0 = 1.8e9
        cpu = 0.0
        try:
            for b in range(rows // batch):
                c0 = time.process_time()
                out = []
                for k in range(batch):
                    i = b * batch + k
                    ts = t0 + i / 2000
                    data = {"x": (i % 10) * 0.3, "y": 0.1, "z": 0.0, "yaw": 0.0}
                    out.append(telemetry_row(f"r{i % 60}", "position", ts, i // 60, data, ts + 0.003))
                if not committer.commit(out):
                    raise RuntimeError("batch not committed")
                cpu += time.process_time() - c0
        finally:
            engine.dispose()
    return cpu / rows * 1e6


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rows", type=int, default=120_000)
    p.add_argument("--batch", type=int, default=1000)
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args()
    runs = [run_once(args.rows, args.batch) for _ in range(args.repeat)]
    median = statistics.median(runs)
    report(
        "ingest rows (sqlite, in process)",
        [
            ("CPU per stored row (us, median)", f"{median:.2f}", "-", "-"),
            ("runs (us)", ", ".join(f"{r:.2f}" for r in runs), "-", "-"),
            ("rows/s of one core at that cost", f"{1e6 / median:.0f}", "-", "-"),
        ],
        {"rows": args.rows, "batch": args.batch, "runs_us": runs, "median_us": median},
    )


if __name__ == "__main__":
    main()
