"""The ingest and history benchmarks run end to end on small settings (their numbers are not checked here:
they belong in docs/performance.md; this proves the harness works and what it measures is consistent)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _result(*argv: str, timeout: float = 240) -> dict:
    proc = subprocess.run([sys.executable, *argv], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    assert lines, proc.stdout[-2000:]
    return json.loads(lines[-1][len("RESULT ") :])


def test_bench_ingest_small() -> None:
    r = _result("bench/bench_ingest.py", "--seconds", "2", "--robots", "5", "--rate", "20")
    assert r["sent"] == 200 and r["stored_distinct"] == 200
    assert r["lost"] == 0 and r["duplicated"] == 0
    assert r["baseline_distinct"] == 200 and r["stored_msg_s"] > 0 and r["ratio"] > 0


def test_bench_mqtt_parse_small() -> None:
    r = _result("bench/bench_mqtt_parse.py", "--messages", "2000", "--repeat", "1")
    assert r["messages"] == 2000 and r["paho_us_per_msg"] > 0 and r["fast_us_per_msg"] > 0
    assert r["fast_msg_s"] > r["paho_msg_s"], "the fast path is the cheaper one"


def test_bench_history_small() -> None:
    r = _result("bench/bench_history.py", "--rows", "5000", "--database", "sqlite", "--repeat", "1")
    assert r["rows"] == 5000 and r["full_points"] > 0 and r["full_method"] == "bucket-mean-minmax"
    assert r["export_rows"] == 5000 and r["full_warm_s"] > 0 and r["rollup_s"] > 0


def test_bench_gap_repair_small() -> None:
    # (2 robots x 60 msg/s x 2 s, of which the broker holds 20 + 10: it drops about 200)
    r = _result(
        "bench/bench_gap_repair.py",
        "--robots",
        "2",
        "--rate",
        "50",
        "--freeze",
        "2",
        "--queue",
        "20",
        "--receive-maximum",
        "10",
    )
    assert r["repaired"] > 0 and r["lost"] == 0 and r["exactly_once"] is True
    assert r["clean_after_s"] > 0 and r["slowest_stream_s"] > 0


def test_bench_health_small() -> None:
    r = _result("bench/bench_health.py", "--samples", "300", "--seconds", "3")
    assert r["sample"]["samples"] == 300 and 0 < r["sample_mean_ms"] <= r["sample_p99_ms"]
    agents = r["agents"]
    assert agents["health_msgs_off"] == 0, "--no-health must publish no health"
    assert agents["health_msgs_on"] >= 2 and agents["cpu_on_s"] > 0 and agents["cpu_off_s"] > 0
