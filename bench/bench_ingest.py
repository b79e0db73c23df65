"""Ingest: how many telemetry messages per second the server stores, next to what the broker can deliver.

A load process publishes pre-encoded raw MQTT PUBLISH packets (QoS 1, PUBACKs read back, several TCP
connections, see rawmqtt.py) for ``--robots`` robots at ``--rate`` Hz each for ``--seconds``. The baseline
is a bare paho subscriber (QoS 1, counting only) on the same broker under the same load, measured first
in the same run (on 2 cores, running it next to the server would take CPU from the thing measured).
Reported: the offered rate, stored msg/s (rows committed per second, first publish to last commit), the
baseline's msg/s, their ratio, lost (published but not stored) and duplicated (stored more than once).

    .venv/bin/python bench/bench_ingest.py [--seconds 60] [--robots 60] [--rate 200] [--database sqlite|postgres]

The default offers 12,000 msg/s: "stored" counts from the first publish to the last commit, so a load of
exactly the 10,000 msg/s target could only ever show a little under it.
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing as mp
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import orjson

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import cpu_seconds, forget_robots, report, rss_mb
from bench.rawmqtt import RawPublisher, publish_packet
from tests.support.procs import Broker, ServerProcess, wait_for

PG_ADMIN = "postgresql://postgres@127.0.0.1:5432/test"


def _packets(robot_ids: list[str], seconds: float, rate: float, t0: float, prefix: str) -> list[list[bytes]]:
    """ticks x robots PUBLISH packets (QoS 1); packet ids are filled in per connection when sent."""
    ticks = int(seconds * rate)
    out = []
    for k in range(ticks):
        ts = t0 + k / rate
        tick = []
        for i, rid in enumerate(robot_ids):
            body = orjson.dumps(
                {
                    "ts": ts,
                    "seq": k,
                    "data": {"x": (i % 10) * 0.3 + k * 1e-3, "y": (i // 10) * 0.3, "z": 0.0, "yaw": 0.0},
                }
            )
            tick.append(publish_packet(f"{prefix}/{rid}/telemetry/position", body, qos=1, packet_id=1))
        out.append(tick)
    return out


def _with_id(packet: bytes, topic_len: int, packet_id: int) -> bytes:
    """Patch the 2-byte packet id after the topic (remaining length is 1-2 bytes: small packets)."""
    rl_bytes = 1 if packet[1] < 0x80 else 2
    pos = 1 + rl_bytes + 2 + topic_len
    return packet[:pos] + packet_id.to_bytes(2, "big") + packet[pos + 2 :]


def load_process(
    host: str,
    port: int,
    robots: int,
    rate: float,
    seconds: float,
    connections: int,
    window: int,
    ready: Any,
    go: Any,
    counters: Any,
    prefix: str = "fleet",
) -> None:
    ids = [f"ingest-{i:04d}" for i in range(robots)]
    pubs = [RawPublisher(host, port, f"bench-ingest-load-{prefix}-{c}", window=window) for c in range(connections)]
    for i, rid in enumerate(ids):
        status = orjson.dumps(
            {
                "online": True,
                "ts": time.time(),
                "agent_version": "bench",
                "capabilities": {"sensors": ["position"], "commands": []},
            }
        )
        pubs[i % connections].publish(f"{prefix}/{rid}/status", status, qos=1, retain=True)
    for p in pubs:
        p.drain(10)
    t0 = time.time()
    ticks = _packets(ids, seconds, rate, t0, prefix)
    topic_lens = [len(f"{prefix}/{rid}/telemetry/position") for rid in ids]
    next_id = [0] * connections
    ready.set()
    go.wait(60)
    start = time.monotonic()
    counters["t_first"] = time.time()
    sent = 0
    for k, tick in enumerate(ticks):
        due = start + k / rate
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        batches: list[list[bytes]] = [[] for _ in range(connections)]
        for i, pkt in enumerate(tick):
            c = i % connections
            next_id[c] = next_id[c] % 65535 + 1
            batches[c].append(_with_id(pkt, topic_lens[i], next_id[c]))
        for c, batch in enumerate(batches):
            pub = pubs[c]
            with pub._cond:  # flow control: at most `window` unacked per connection
                while pub.sent_qos1 + len(batch) - pub.acked > pub.window:
                    if not pub._cond.wait(10):
                        raise TimeoutError("no PUBACK for 10 s")
                pub.sent_qos1 += len(batch)
            pub.send_many(batch)
        sent += len(tick)
    counters["t_last_sent"] = time.time()
    for p in pubs:
        p.drain(30)
    counters["t_last_acked"] = time.time()
    counters["sent"] = sent
    counters["acked"] = sum(p.acked for p in pubs) - robots  # minus the statuses
    for i, rid in enumerate(ids):
        pubs[i % connections].publish(f"{prefix}/{rid}/status", b"", qos=1, retain=True)
    for p in pubs:
        p.drain(10)
        p.close()


class Baseline:
    """A bare paho subscriber counting (robot, seq) of every telemetry message it gets."""

    def __init__(self, host: str, port: int, prefix: str) -> None:
        import paho.mqtt.client as mqtt
        from paho.mqtt.enums import CallbackAPIVersion

        self.seen: set[bytes] = set()
        self.count = 0
        self.last_at = 0.0
        self._lock = threading.Lock()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-baseline-{uuid.uuid4().hex[:6]}")
        self.client.on_connect = lambda c, *_: c.subscribe(f"{prefix}/+/telemetry/#", qos=1)
        self.client.on_message = self._on_message
        self.client.connect(host, port, keepalive=30)
        self.client.loop_start()

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        # the topic and the seq field identify a message; no JSON parsing (this is the cheap baseline)
        payload = bytes(msg.payload)
        i = payload.find(b'"seq":')
        key = msg.topic.encode() + payload[i : i + 20]
        with self._lock:
            self.count += 1
            self.seen.add(key)
            self.last_at = time.time()

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@contextlib.contextmanager
def database(kind: str, work: Path) -> Iterator[str]:
    if kind == "sqlite":
        yield f"sqlite:///{work / 'fleet.db'}"
        return
    import psycopg

    name = f"fleet_bench_{uuid.uuid4().hex[:8]}"
    with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"
    finally:
        with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def _stored(url: str) -> tuple[int, int, float | None]:
    """(rows, distinct (robot, seq), None) for the bench robots."""
    from sqlalchemy import create_engine, text

    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            rows, distinct = conn.execute(
                text(
                    "SELECT count(*), count(DISTINCT robot_id || ':' || CAST(seq AS TEXT)) FROM telemetry "
                    "WHERE stream = 'position' AND robot_id LIKE 'ingest-%'"
                )
            ).one()
    finally:
        engine.dispose()
    return int(rows), int(distinct), None


def run(args: argparse.Namespace) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="fleet-bench-ingest-") as tmp:
        work = Path(tmp)
        broker = Broker(work, extra_conf="max_queued_messages 2000000\n")
        broker.start()
        try:
            with database(args.database, work) as url:
                server = ServerProcess(broker, url, work)
                server.start()
                try:
                    result = _measure(args, broker, server, url)
                    forget_robots(server)
                    return result
                finally:
                    server.stop()
        finally:
            broker.stop()


def _load(args: argparse.Namespace, broker: Broker, prefix: str, on_go: Any = None) -> dict[str, Any]:
    """One load phase (a separate process): returns its counters once every PUBACK came back."""
    ctx = mp.get_context("spawn")
    ready, go = ctx.Event(), ctx.Event()
    manager = ctx.Manager()
    counters = manager.dict()
    loader = ctx.Process(
        target=load_process,
        args=(
            broker.host,
            broker.port,
            args.robots,
            args.rate,
            args.seconds,
            args.connections,
            args.window,
            ready,
            go,
            counters,
            prefix,
        ),
    )
    loader.start()
    if not ready.wait(120):
        raise RuntimeError("load process did not get ready")
    time.sleep(1.0)  # robots registered
    if on_go is not None:
        on_go()
    go.set()
    loader.join(args.seconds * 3 + 120)
    got = dict(counters)
    manager.shutdown()
    if "sent" not in got:
        raise RuntimeError(f"the load process failed (exit code {loader.exitcode})")
    return got


def _measure(args: argparse.Namespace, broker: Broker, server: ServerProcess, url: str) -> dict[str, Any]:
    # Phase 1, the baseline: the same load on the same broker under the prefix "bench" (same length as
    # "fleet", so the same packet sizes), which the server does not subscribe to; the bare subscriber gets
    # the machine to itself as the server does in phase 2 (run side by side they would share 2 cores).
    baseline = Baseline(broker.host, broker.port, "bench")
    try:
        wait_for(lambda: baseline.client.is_connected(), 10, what="baseline subscriber")
        time.sleep(0.3)  # SUBACK
        base_got = _load(args, broker, "bench")
        base_sent = int(base_got["sent"])
        wait_for(lambda: len(baseline.seen) >= base_sent or time.time() - baseline.last_at > 3, 60)
        base_s = max(baseline.last_at - float(base_got["t_first"]), 1e-6)
        base_received, base_distinct = baseline.count, len(baseline.seen)
    finally:
        baseline.close()

    # Phase 2: the fleet server stores the same load.
    pid = server.proc.pid  # type: ignore[union-attr]
    cpu0: list[float] = []
    got = _load(args, broker, "fleet", on_go=lambda: cpu0.append(cpu_seconds(pid)))
    sent = int(got["sent"])
    t_first = float(got["t_first"])
    # wait until the store stops growing (everything the broker acked is in, or nothing moves for 5 s)
    last, last_change, t_done = -1, time.monotonic(), time.time()
    while time.monotonic() - last_change < 5.0:
        rows, distinct, _ = _stored(url)
        if rows != last:
            last, last_change, t_done = rows, time.monotonic(), time.time()
        if distinct >= sent:
            break
        time.sleep(0.1)
    rows, distinct, _ = _stored(url)
    cpu = cpu_seconds(pid) - cpu0[0]
    rss = rss_mb(pid)
    with server.client() as c:
        stats = c.get("/api/stats").json()
    stored_s = max(t_done - t_first, 1e-6)
    return {
        "database": args.database,
        "robots": args.robots,
        "rate_hz": args.rate,
        "seconds": args.seconds,
        "offered_msg_s": args.robots * args.rate,
        "sent": sent,
        "stored_rows": rows,
        "stored_distinct": distinct,
        "stored_msg_s": distinct / stored_s,
        "baseline_received": base_received,
        "baseline_distinct": base_distinct,
        "baseline_lost": base_sent - base_distinct,
        "baseline_msg_s": base_distinct / base_s,
        "ratio": (distinct / stored_s) / (base_distinct / base_s),
        "lost": sent - distinct,
        "duplicated": rows - distinct,
        "lag_s": t_done - float(got["t_last_acked"]),
        "server_cpu_s": cpu,
        "server_cpu_cores": cpu / stored_s,
        "server_rss_mb": rss,
        "writer_batches": stats["writer"]["batches"],
        "mqtt_dropped": stats["mqtt"].get("dropped", 0),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--robots", type=int, default=60)
    p.add_argument("--rate", type=float, default=200.0, help="messages per second per robot")
    p.add_argument("--connections", type=int, default=4)
    p.add_argument("--window", type=int, default=2000, help="unacked QoS 1 messages per connection")
    p.add_argument("--database", choices=["sqlite", "postgres"], default="sqlite")
    args = p.parse_args()
    r = run(args)
    ok = lambda c: "yes" if c else "NO"  # noqa: E731
    report(
        f"ingest ({r['database']})",
        [
            ("offered (msg/s)", f"{r['offered_msg_s']:.0f}", "-", "-"),
            ("stored (msg/s)", f"{r['stored_msg_s']:.0f}", ">= 10000", ok(r["stored_msg_s"] >= 10_000)),
            ("baseline paho subscriber (msg/s)", f"{r['baseline_msg_s']:.0f}", "-", "-"),
            ("stored / baseline", f"{r['ratio']:.2f}", ">= 0.7", ok(r["ratio"] >= 0.7)),
            ("lost", str(r["lost"]), "0", ok(r["lost"] == 0)),
            ("duplicated", str(r["duplicated"]), "0", ok(r["duplicated"] == 0)),
            ("store lag after last publish (s)", f"{r['lag_s']:.2f}", "-", "-"),
            ("server CPU (cores)", f"{r['server_cpu_cores']:.2f}", "-", "-"),
            ("server RSS (MB)", f"{r['server_rss_mb']:.0f}", "-", "-"),
        ],
        r,
    )


if __name__ == "__main__":
    main()
