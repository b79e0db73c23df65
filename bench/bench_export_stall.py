"""Exports left unread (issue 28): readers never starve the writer or the control plane.

The real server (Mosquitto, fleet-server on SQLite) with a stored stream of ``--rows`` rows of about 1 KB
(an export larger than the sockets' buffers). Two phases of ``--seconds`` each, with simulated robots
publishing position at QoS 1 throughout (``--robots`` x ``--rate`` Hz) and /api/health asked every 50 ms:
first with no export, then with ``--exports`` raw CSV exports opened by raw sockets that send the request
and never read (a laptop on weak pool Wi-Fi). The server runs with its export caps raised to
``--exports`` (all are admitted and stay open: the hard case) unless ``--default-caps``.

Reported per phase: health latency (max, p99) and failures, the QoS 1 acknowledgement latency (the
broker's PUBACK to the robot follows the server's commit), and stored-vs-sent counts (at the end of the
phase, and once drained). Targets: health within 0.5 s throughout; every message stored.

    .venv/bin/python bench/bench_export_stall.py [--exports 40] [--seconds 20] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path
from typing import Any

import orjson

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import percentile, report, stack
from bench.rawhttp import open_unread, response_status
from fleet_protocol import Topics, encode_telemetry
from tests.support.exports import fill_big
from tests.support.mqtt import MqttProbe
from tests.support.procs import http_client, wait_for

TOPICS = Topics()
HEALTH_TARGET_S = 0.5
EXPORT = "/api/robots/big/telemetry?stream=blob&raw=true&format=csv"


class HealthSampler(threading.Thread):
    """GET /api/health every ``interval`` s; latency of each answer, and the failures."""

    def __init__(self, base_url: str, interval: float = 0.05) -> None:
        super().__init__(daemon=True)
        self.base_url, self.interval = base_url, interval
        self.latencies: list[float] = []
        self.failures = 0
        self.stopping = threading.Event()

    def run(self) -> None:
        with http_client(base_url=self.base_url, timeout=30.0) as http:
            while not self.stopping.is_set():
                t0 = time.perf_counter()
                try:
                    ok = http.get("/api/health").json()["database"]["ok"] is True
                except Exception:
                    ok = False
                self.latencies.append(time.perf_counter() - t0)
                self.failures += not ok
                self.stopping.wait(self.interval)


class Robots:
    """Simulated robots publishing position at QoS 1 through one paho client; the PUBACK latency of each."""

    def __init__(self, probe: MqttProbe, robots: int) -> None:
        self.probe = probe
        self.ids = [f"live-{i}" for i in range(robots)]
        self.seq = dict.fromkeys(self.ids, 0)
        self.sent_at: dict[int, float] = {}
        self.acked_at: dict[int, float] = {}  # a PUBACK seen before its publish call returned
        self.ack_s: list[float] = []
        self._lock = threading.Lock()
        probe.client.on_publish = self._acked
        for rid in self.ids:
            probe.publish(TOPICS.status(rid), status(["position"]), retain=True)

    def _acked(self, _client: Any, _userdata: Any, mid: int, *_rest: Any) -> None:
        now = time.perf_counter()
        with self._lock:
            t0 = self.sent_at.pop(mid, None)
            if t0 is None:
                self.acked_at[mid] = now
            else:
                self.ack_s.append(now - t0)

    def run(self, seconds: float, rate: float) -> int:
        """Publish for ``seconds`` at ``rate`` Hz per robot; returns the messages sent."""
        sent, start = 0, time.monotonic()
        for k in range(int(seconds * rate)):
            delay = start + k / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            for rid in self.ids:
                self.seq[rid] += 1
                payload = encode_telemetry(self.seq[rid], {"x": k * 1e-3, "y": 0.0, "z": 0.0, "yaw": 0.0})
                t0 = time.perf_counter()
                mid = self.probe.client.publish(TOPICS.telemetry(rid, "position"), payload, qos=1).mid
                with self._lock:
                    done = self.acked_at.pop(mid, None)
                    if done is None:
                        self.sent_at[mid] = t0
                    else:
                        self.ack_s.append(done - t0)
                sent += 1
        return sent


def status(sensors: list[str], online: bool = True) -> bytes:
    return orjson.dumps(
        {
            "online": online,
            "ts": time.time(),
            "agent_version": "bench",
            "capabilities": {"sensors": sensors, "commands": []},
        }
    )


def stored(http: Any, robots: list[str]) -> int:
    total = 0
    for rid in robots:
        counts = {s["stream"]: s["count"] for s in http.get(f"/api/robots/{rid}/streams").json()}
        total += counts.get("position", 0)
    return total


def phase(server: Any, robots: Robots, http: Any, seconds: float, rate: float, sent_before: int) -> dict[str, Any]:
    sampler = HealthSampler(server.base_url)
    robots.ack_s.clear()
    sampler.start()
    sent = sent_before + robots.run(seconds, rate)
    at_end = stored(http, robots.ids)
    sampler.stopping.set()
    sampler.join(60)
    wait_for(lambda: stored(http, robots.ids) >= sent, 60, what="every message stored")
    lat = sampler.latencies
    return {
        "health_samples": len(lat),
        "health_max_ms": max(lat) * 1000,
        "health_p99_ms": percentile(lat, 99) * 1000,
        "health_failures": sampler.failures,
        "ack_p99_ms": percentile(robots.ack_s, 99) * 1000,
        "ack_max_ms": max(robots.ack_s) * 1000,
        "sent": sent - sent_before,
        "stored_at_end": at_end - sent_before,
        "stored": stored(http, robots.ids) - sent_before,
        "total_sent": sent,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--exports", type=int, default=40, help="raw CSV exports opened and never read")
    p.add_argument("--seconds", type=float, default=20.0, help="length of each phase")
    p.add_argument("--robots", type=int, default=5)
    p.add_argument("--rate", type=float, default=20.0, help="position messages per second per robot")
    p.add_argument("--rows", type=int, default=8000, help="rows of the exported stream (about 1 KB each)")
    p.add_argument("--default-caps", action="store_true", help="keep the export caps (most exports get 429)")
    p.add_argument("--quick", action="store_true", help="a small setting: 12 exports, 2 s phases")
    args = p.parse_args()
    if args.quick:
        args.exports, args.seconds, args.robots, args.rows = 12, 2.0, 2, 6000
    env = (
        {}
        if args.default_caps
        else {
            "FLEET_EXPORT_MAX_CONCURRENT": str(args.exports),
            "FLEET_EXPORT_MAX_PER_CLIENT": str(args.exports),
        }
    )
    with stack(**env) as (broker, server, _work), http_client(base_url=server.base_url, timeout=30.0) as http:
        http.headers["Authorization"] = f"Bearer {server.token}"
        probe = MqttProbe(broker.host, broker.port)
        probe.publish(TOPICS.status("big"), status(["blob"]), retain=True)
        wait_for(lambda: http.get("/api/robots/big").status_code == 200, 30, what="the export's robot")
        fill_big(server.database_url, rows=args.rows)
        robots = Robots(probe, args.robots)
        wait_for(lambda: len(http.get("/api/robots").json()) == args.robots + 1, 30, what="the robots")

        quiet = phase(server, robots, http, args.seconds, args.rate, 0)
        socks = [
            open_unread("127.0.0.1", server.port, EXPORT, {"Authorization": f"Bearer {server.token}"})
            for _ in range(args.exports)
        ]
        try:
            statuses = [response_status(s, timeout=60)[0] for s in socks]
            stalled = phase(server, robots, http, args.seconds, args.rate, quiet["total_sent"])
            exports = http.get("/api/stats").json()["exports"]
        finally:
            for s in socks:
                s.close()
        for rid in ["big", *robots.ids]:  # offline, so that the stack's cleanup forgets them at once
            probe.publish(TOPICS.status(rid), status([], online=False), retain=True)
        probe.close()

    ok_health = stalled["health_max_ms"] <= HEALTH_TARGET_S * 1000 and stalled["health_failures"] == 0
    ok_stored = stalled["stored"] == stalled["sent"] and quiet["stored"] == quiet["sent"]
    rows = [
        (
            "exports opened, unread (200 / refused)",
            f"{statuses.count(200)} / {len(statuses) - statuses.count(200)}",
            "",
            "",
        ),
        ("exports still open at the end", str(exports["running"]), "", ""),
    ]
    for name, r in (("no export", quiet), (f"{args.exports} unread", stalled)):
        rows += [
            (
                f"{name}: /api/health max",
                f"{r['health_max_ms']:.1f} ms",
                f"<= {HEALTH_TARGET_S * 1000:.0f} ms",
                "yes" if r["health_max_ms"] <= HEALTH_TARGET_S * 1000 else "NO",
            ),
            (f"{name}: /api/health p99 ({r['health_samples']})", f"{r['health_p99_ms']:.1f} ms", "", ""),
            (f"{name}: QoS 1 ack p99 / max", f"{r['ack_p99_ms']:.0f} / {r['ack_max_ms']:.0f} ms", "", ""),
            (
                f"{name}: stored / sent",
                f"{r['stored']} / {r['sent']}",
                "all",
                "yes" if r["stored"] == r["sent"] else "NO",
            ),
            (f"{name}: stored when sending ended", f"{r['stored_at_end']}", "", ""),
        ]
    report(
        "export-stall",
        rows,
        {
            "exports": args.exports,
            "admitted": statuses.count(200),
            "open_at_end": exports["running"],
            "quiet": quiet,
            "stalled": stalled,
            "health_max_ms": stalled["health_max_ms"],
            "health_p99_ms": stalled["health_p99_ms"],
            "sent": stalled["sent"],
            "stored": stalled["stored"],
            "ok": ok_health and ok_stored,
        },
    )
    return 0 if ok_stored and stalled["health_failures"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
