"""Health stream cost (issue 20: <= 1 ms of CPU per sample).

(a) In process: the CPU time of one health sample (``HealthPlugin.sample``: simulated battery, psutil CPU /
memory / disk / uptimes, SoC temperature, /proc/net/wireless, clock offset, motor fault), per sample over
many samples, by the thread's CPU clock. (b) Two simulated agents against one real broker over the same
seconds, one with the health stream (the default) and one with ``--no-health``: their CPU from psutil's
process CPU times, and the difference per health message published.

    .venv/bin/python bench/bench_health.py [--samples 5000] [--seconds 60]
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import percentile, report
from fleet_protocol import Topics
from robot_agent.link.clock_sync import ClockSync
from robot_agent.motors.sim import SimMotorDriver
from robot_agent.sensors import SENSOR_REGISTRY
from robot_agent.sensors.base import SensorContext
from robot_agent.sensors.health import HealthPlugin
from robot_agent.sensors.supervisor import build_plugins
from robot_agent.sim.world import SimWorld
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker

TARGET_MS = 1.0


def sample_cost(samples: int) -> dict[str, float]:
    """CPU ms of one sample (mean, p50, p99), as the agent's loop would take it: in an event loop."""
    motors = SimMotorDriver(SimWorld())
    shared: dict[str, Any] = {"motors": motors, "clock": ClockSync(lambda b: None)}
    ctx = SensorContext(
        robot_id="bench",
        emit=lambda s, d: None,
        emit_retained=lambda s, d: None,
        emit_camera=lambda s, p: None,
        shared=shared,
    )
    [plugin] = build_plugins([{"type": "health", "battery": {"type": "sim"}}], SENSOR_REGISTRY, lambda: ctx)
    assert isinstance(plugin, HealthPlugin)
    costs: list[float] = []

    async def run() -> None:
        await plugin.start()
        motors.set(0.5, 0.5)
        for _ in range(50):  # warm up (imports, first file opens)
            plugin.sample()
        for _ in range(samples):
            t0 = time.thread_time_ns()
            plugin.sample()
            costs.append((time.thread_time_ns() - t0) / 1e6)
        await plugin.stop()

    asyncio.run(run())
    motors.close()
    return {
        "mean_ms": sum(costs) / len(costs),
        "p50_ms": percentile(costs, 50),
        "p99_ms": percentile(costs, 99),
        "samples": float(samples),
    }


def agents_cpu(seconds: float) -> dict[str, float]:
    """Two agents side by side for ``seconds``: CPU seconds each, health messages seen from each."""
    with tempfile.TemporaryDirectory(prefix="fleet-bench-") as tmp:
        work = Path(tmp)
        broker = Broker(work)
        broker.start()
        topics = Topics()
        probe = MqttProbe(broker.host, broker.port, [topics.all_telemetry()])
        on = AgentProcess("health-on", broker, work, [])
        off = AgentProcess("health-off", broker, work, ["--no-health"])
        try:
            on.start()
            off.start()
            time.sleep(3.0)  # both connected and past start-up
            procs = {name: psutil.Process(a.proc.pid) for name, a in (("on", on), ("off", off))}  # type: ignore[union-attr]
            cpu0 = {n: sum(p.cpu_times()[:2]) for n, p in procs.items()}

            health_topics = {
                "on": topics.telemetry("health-on", "health"),
                "off": topics.telemetry("health-off", "health"),
            }

            def health_seen() -> dict[str, int]:
                counts = dict.fromkeys(health_topics, 0)
                for m in probe.matching(lambda m: m.topic in health_topics.values()):
                    counts["on" if m.topic == health_topics["on"] else "off"] += 1
                return counts

            seen0 = health_seen()
            t0 = time.monotonic()
            time.sleep(seconds)
            elapsed = time.monotonic() - t0
            cpu = {n: sum(p.cpu_times()[:2]) - cpu0[n] for n, p in procs.items()}
            seen = {n: count - seen0[n] for n, count in health_seen().items()}
            assert on.alive() and off.alive(), (on.output()[-2000:], off.output()[-2000:])
        finally:
            on.stop()
            off.stop()
            probe.close()
            broker.stop()
    extra = cpu["on"] - cpu["off"]
    return {
        "seconds": elapsed,
        "cpu_on_s": cpu["on"],
        "cpu_off_s": cpu["off"],
        "cores_on": cpu["on"] / elapsed,
        "cores_off": cpu["off"] / elapsed,
        "health_msgs_on": float(seen["on"]),
        "health_msgs_off": float(seen["off"]),
        "extra_ms_per_msg": extra * 1000 / seen["on"] if seen["on"] else float("nan"),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--samples", type=int, default=5000)
    p.add_argument("--seconds", type=float, default=60.0)
    args = p.parse_args()
    cost = sample_cost(args.samples)
    agents = agents_cpu(args.seconds)
    ok = lambda c: "yes" if c else "NO"  # noqa: E731
    report(
        "health",
        [
            (
                "one sample, CPU mean (ms)",
                f"{cost['mean_ms']:.3f}",
                f"<= {TARGET_MS}",
                ok(cost["mean_ms"] <= TARGET_MS),
            ),
            ("one sample, CPU p99 (ms)", f"{cost['p99_ms']:.3f}", "-", "-"),
            ("agent CPU, health on (cores)", f"{agents['cores_on']:.4f}", "-", "-"),
            ("agent CPU, health off (cores)", f"{agents['cores_off']:.4f}", "-", "-"),
            (
                "health messages (on / off)",
                f"{agents['health_msgs_on']:.0f} / {agents['health_msgs_off']:.0f}",
                "-",
                ok(agents["health_msgs_off"] == 0 and agents["health_msgs_on"] > 0),
            ),
            ("on - off, per health message (ms)", f"{agents['extra_ms_per_msg']:.2f}", "-", "-"),
        ],
        {
            "sample_mean_ms": cost["mean_ms"],
            "sample_p99_ms": cost["p99_ms"],
            "cores_on": agents["cores_on"],
            "cores_off": agents["cores_off"],
            "extra_ms_per_msg": agents["extra_ms_per_msg"],
            "sample": cost,
            "agents": agents,
        },
    )


if __name__ == "__main__":
    main()
