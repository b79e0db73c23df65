"""Agent memory: resident size of a simulated agent (a) with position + imu, (b) with camera + apriltag
too, after it has run for a while against a real broker (targets from issue 8: <= 80 MB / <= 150 MB).
RSS and its peak come from /proc/PID/status (VmRSS / VmHWM).

    .venv/bin/python bench/bench_agent_memory.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import cpu_seconds, report
from tests.support.procs import AgentProcess, Broker


def vm(pid: int, key: str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def threads(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Threads:"):
            return int(line.split()[1])
    return 0


def measure(broker: Broker, work: Path, name: str, args: list[str], seconds: float) -> dict[str, float]:
    agent = AgentProcess(name, broker, work, args)
    agent.start()
    try:
        time.sleep(2.0)
        pid = agent.proc.pid  # type: ignore[union-attr]
        cpu0, t0 = cpu_seconds(pid), time.monotonic()
        time.sleep(seconds)
        assert agent.alive(), agent.output()[-2000:]
        return {
            "rss_mb": vm(pid, "VmRSS"),
            "peak_rss_mb": vm(pid, "VmHWM"),
            "cpu_cores": (cpu_seconds(pid) - cpu0) / (time.monotonic() - t0),
            "threads": threads(pid),
        }
    finally:
        agent.stop()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=20.0)
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="fleet-bench-") as tmp:
        work = Path(tmp)
        broker = Broker(work)
        broker.start()
        try:
            basic = measure(broker, work, "mem-basic", [], args.seconds)
            camera = measure(broker, work, "mem-camera", ["--camera"], args.seconds)
        finally:
            broker.stop()
    ok = lambda c: "yes" if c else "NO"  # noqa: E731
    report(
        "agent-memory",
        [
            ("position+imu RSS (MB)", f"{basic['rss_mb']:.0f}", "<= 80", ok(basic["rss_mb"] <= 80)),
            ("position+imu peak RSS (MB)", f"{basic['peak_rss_mb']:.0f}", "<= 80", ok(basic["peak_rss_mb"] <= 80)),
            ("position+imu CPU (cores)", f"{basic['cpu_cores']:.3f}", "-", "-"),
            ("+camera+apriltag RSS (MB)", f"{camera['rss_mb']:.0f}", "<= 150", ok(camera["rss_mb"] <= 150)),
            (
                "+camera+apriltag peak RSS (MB)",
                f"{camera['peak_rss_mb']:.0f}",
                "<= 150",
                ok(camera["peak_rss_mb"] <= 150),
            ),
            ("+camera+apriltag CPU (cores)", f"{camera['cpu_cores']:.3f}", "-", "-"),
            ("threads (basic / camera)", f"{basic['threads']} / {camera['threads']}", "-", "-"),
        ],
        {"seconds": args.seconds, "basic": basic, "camera": camera},
    )


if __name__ == "__main__":
    main()
