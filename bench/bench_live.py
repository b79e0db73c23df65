"""Live path under fleet load: publish -> WebSocket latency, REST command round trip, server RSS/CPU.

N synthetic robots publish ``position`` at R Hz with QoS 1 from a separate load process (raw MQTT
packets, several connections, see rawmqtt.py); K WebSocket clients subscribed to everything measure the
age of each telemetry message on arrival (its ``ts`` is set when the load process encodes it); real
simulated agents answer ``stop`` commands sent with ``POST ...?wait`` while the load runs.

    .venv/bin/python bench/bench_live.py [--robots 100] [--rate 20] [--clients 5] [--seconds 20]
    .venv/bin/python bench/bench_live.py --robots 200 --seconds 20     # the server-memory setting
    .venv/bin/python bench/bench_live.py --phase spread                # robots at independent phases
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import multiprocessing as mp
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import orjson

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import cpu_seconds, percentile, report, rss_mb, stack
from bench.live_commands import RTT_STAGES, command_figures, command_process
from bench.rawmqtt import RawPublisher
from tests.support.procs import AgentProcess, wait_for


def load_process(
    host: str,
    port: int,
    robots: int,
    rate: float,
    seconds: float,
    connections: int,
    started: Any,
    stop: Any,
    counters: Any,
    phase: str = "burst",
    motion: str = "still",
) -> None:
    """Status once (retained), then position at ``rate`` Hz per robot until ``seconds`` or ``stop``.
    ``phase="burst"``: every robot publishes at the start of each tick (the worst case); ``"spread"``: robot
    i publishes i/robots of a tick later, as independent robots do. ``motion="circle"``: each robot drives a
    0.3 m circle (0.5 m/s) instead of standing still, so the dashboard draws full trails."""
    ids = [f"load-{i:03d}" for i in range(robots)]
    pubs = [RawPublisher(host, port, f"bench-load-{c}", window=2000) for c in range(connections)]
    for i, rid in enumerate(ids):
        status = orjson.dumps(
            {
                "online": True,
                "ts": time.time(),
                "agent_version": "bench",
                "capabilities": {"sensors": ["position"], "commands": []},
            }
        )
        pubs[i % connections].publish(f"fleet/{rid}/status", status, qos=1, retain=True)
    started.set()
    seq = 0
    t0 = time.monotonic()
    next_tick = t0
    sent = 0
    while time.monotonic() - t0 < seconds and not stop.is_set():
        tick_start = next_tick
        for i, rid in enumerate(ids):
            if phase == "spread":
                wait = tick_start + i / (robots * rate) - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
            if motion == "circle":
                a = seq / (rate * 0.6) + i  # 0.5 m/s on a 0.3 m circle around the robot's grid point
                pose = {
                    "x": (i % 10) * 0.4 - 1.8 + 0.3 * math.cos(a),
                    "y": (i // 10) * 0.4 - 1.8 + 0.3 * math.sin(a),
                    "z": 0.0,
                    "yaw": a + math.pi / 2,
                }
            else:
                pose = {"x": (i % 10) * 0.3, "y": (i // 10) * 0.3, "z": 0.0, "yaw": 0.0}
            body = orjson.dumps({"ts": time.time(), "seq": seq, "data": pose})
            pubs[i % connections].publish(f"fleet/{rid}/telemetry/position", body, qos=1)
        sent += len(ids)
        seq += 1
        next_tick += 1.0 / rate
        delay = next_tick - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    for pub in pubs:
        pub.drain(10)
    counters["sent"] = sent
    for i, rid in enumerate(ids):  # gone, as an agent that stops says it; then leave the broker clean
        offline = orjson.dumps(
            {
                "online": False,
                "ts": time.time(),
                "agent_version": "bench",
                "capabilities": {"sensors": ["position"], "commands": []},
            }
        )
        pubs[i % connections].publish(f"fleet/{rid}/status", offline, qos=1)
        pubs[i % connections].publish(f"fleet/{rid}/status", b"", qos=1, retain=True)
    for pub in pubs:
        pub.drain(10)
        pub.close()


@contextlib.contextmanager
def fleet_load(
    host: str,
    port: int,
    robots: int,
    rate: float,
    seconds: float,
    connections: int = 4,
    phase: str = "burst",
    motion: str = "still",
) -> Iterator[Any]:
    """:func:`load_process` in a process of its own, started (statuses sent) when this enters, stopped and
    joined when it exits; yields its multiprocessing manager (for results other processes hand back)."""
    ctx = mp.get_context("spawn")
    started, stop = ctx.Event(), ctx.Event()
    manager = ctx.Manager()
    # held here until the loader is joined: a proxy dropped by this process before the child has taken its
    # own reference lets the manager delete the dict (KeyError in the child's last write)
    counters = manager.dict()
    loader = ctx.Process(
        target=load_process,
        args=(host, port, robots, rate, seconds, connections, started, stop, counters, phase, motion),
    )
    loader.start()
    started.wait(30)
    try:
        yield manager
    finally:
        stop.set()
        loader.join(30)
        manager.shutdown()


#: a message older than this on arrival is "late": the bench records when, and at which client
LATE_S = 0.05


async def ws_client(
    url: str,
    latencies: list[float],
    stop: asyncio.Event,
    counts: dict[str, int],
    late: list[tuple[float, float, int]] | None = None,
    client_no: int = 0,
) -> None:
    """Subscribe to every robot's position; append each message's age on arrival to ``latencies`` (and
    (arrival, age, client_no) to ``late`` for late ones: where a stall was, and whom it hit)."""
    import websockets

    async with websockets.connect(url, max_size=None) as ws:
        await ws.send(orjson.dumps({"type": "subscribe", "robots": ["*"], "streams": ["position"]}).decode())
        while not stop.is_set():
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue
            now = time.time()
            for msg in orjson.loads(frame):
                if msg.get("type") == "telemetry":
                    age = now - msg["ts"]
                    latencies.append(age)
                    if late is not None and age > LATE_S:
                        late.append((now, age, client_no))
                    counts["received"] = counts.get("received", 0) + 1


def baseline_latencies(host: str, port: int, seconds: float) -> list[float]:
    """The floor: a bare paho subscriber (QoS 1, same broker and load, no server in between) timing each
    position message the same way the WebSocket clients do. Run before them, alone, so neither takes CPU
    from the other on a small machine."""
    import paho.mqtt.client as mqtt
    from paho.mqtt.enums import CallbackAPIVersion

    latencies: list[float] = []

    def on_message(client: Any, userdata: Any, msg: Any) -> None:
        latencies.append(time.time() - orjson.loads(msg.payload)["ts"])

    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="bench-live-baseline", protocol=mqtt.MQTTv5)
    client.on_message = on_message
    client.on_connect = lambda c, u, f, rc, p: c.subscribe("fleet/+/telemetry/position", qos=1)
    client.connect(host, port)
    client.loop_start()
    time.sleep(1)
    latencies.clear()
    time.sleep(seconds)
    client.loop_stop()
    client.disconnect()
    return latencies


async def loop_lag(stop: asyncio.Event, worst: list[tuple[float, float]], interval: float = 0.01) -> None:
    """The bench process's own event-loop lag (its clients measure on that loop): (lag, when) > 50 ms."""
    while not stop.is_set():
        t = time.monotonic()
        await asyncio.sleep(interval)
        lag = time.monotonic() - t - interval
        if lag > LATE_S:
            worst.append((lag, time.time()))


def late_summary(late: list[tuple[float, float, int]], t0: float) -> dict[str, Any]:
    """Late messages (older than LATE_S on arrival): how many, the worst age, over which seconds of the run
    they arrived and at how many clients. One short window at every client: a stall upstream of all of
    them (server, broker); at one client only: that client."""
    if not late:
        return {"messages": 0}
    arrivals = [t for t, _, _ in late]
    return {
        "messages": len(late),
        "worst_ms": round(max(a for _, a, _ in late) * 1000, 1),
        "from_s": round(min(arrivals) - t0, 2),
        "to_s": round(max(arrivals) - t0, 2),
        "from_utc": time.strftime("%H:%M:%S", time.gmtime(min(arrivals))) + f"{min(arrivals) % 1:.3f}"[1:],
        "clients": len({c for _, _, c in late}),
    }


async def run(args: argparse.Namespace) -> dict[str, Any]:
    with stack(**dict(kv.split("=", 1) for kv in args.server_env)) as (broker, server, work):
        agents = [AgentProcess(f"bench-agent-{i}", broker, work) for i in range(args.agents)]
        for a in agents:
            a.start()
        headers = dict(server.client().headers)
        with server.client() as c:
            for a in agents:
                wait_for(
                    lambda a=a: (
                        c.get(f"/api/robots/{a.robot_id}").status_code == 200
                        and c.get(f"/api/robots/{a.robot_id}").json()["online"]
                    ),
                    30,
                    what="agent online",
                )
        load_s = args.seconds + args.baseline_seconds + 7
        with fleet_load(
            broker.host, broker.port, args.robots, args.rate, load_s, args.connections, args.phase
        ) as manager:
            await asyncio.sleep(2)  # warm-up: robots registered, clients connected
            base = await asyncio.to_thread(baseline_latencies, broker.host, broker.port, args.baseline_seconds)
            latencies: list[float] = []
            counts: dict[str, int] = {}
            stop = asyncio.Event()
            url = server.ws_url  # carries the admin token as ?token=
            late: list[tuple[float, float, int]] = []
            clients = [
                asyncio.create_task(ws_client(url, latencies, stop, counts, late, i)) for i in range(args.clients)
            ]
            await asyncio.sleep(1)
            latencies.clear()
            late.clear()
            bench_lags: list[tuple[float, float]] = []
            lag_task = asyncio.create_task(loop_lag(stop, bench_lags))
            cpu0, t0, t_wall0 = cpu_seconds(server.proc.pid), time.monotonic(), time.time()  # type: ignore[union-attr]
            rtt_out = manager.list()
            commander = mp.get_context("spawn").Process(
                target=command_process,
                args=(server.base_url, headers, [a.robot_id for a in agents], args.seconds, rtt_out),
            )
            commander.start()
            await asyncio.to_thread(commander.join, args.seconds + 60)
            cpu = (cpu_seconds(server.proc.pid) - cpu0) / (time.monotonic() - t0)  # type: ignore[union-attr]
            rss = rss_mb(server.proc.pid)  # type: ignore[union-attr]
            # the clients stop before anything here blocks this loop (reading the results from the manager
            # took long enough to show up as late messages at every client)
            stop.set()
            await asyncio.gather(*clients, lag_task, return_exceptions=True)
            commands = command_figures(list(rtt_out))
        with server.client() as c:
            stats = c.get("/api/stats").json()
        server_log = server.output()
        if args.server_log:
            Path(args.server_log).write_text(server_log)
        stall_log = [line for line in server_log.splitlines() if "event loop stalled" in line]
        for a in agents:
            a.stop()
    return {
        "robots": args.robots,
        "rate_hz": args.rate,
        "clients": args.clients,
        "seconds": args.seconds,
        "phase": args.phase,
        "ws_p50_ms": percentile(latencies, 50) * 1000,
        "ws_p99_ms": percentile(latencies, 99) * 1000,
        "ws_messages": len(latencies),
        "baseline_p50_ms": percentile(base, 50) * 1000,
        "baseline_p99_ms": percentile(base, 99) * 1000,
        "baseline_messages": len(base),
        **commands,
        "ws_late": late_summary(late, t_wall0),
        "server_loop": stats.get("event_loop", {}),
        "writer_slowest_batch_ms": stats["writer"].get("slowest_batch_ms"),
        "bench_loop_lags": [(round(lag * 1000), round(at - t_wall0, 2)) for lag, at in bench_lags],
        "server_stall_log": stall_log[:3],
        "server_rss_mb": rss,
        "server_cpu_cores": cpu,
        "ws_dropped": stats["ws"].get("dropped", 0),
        "mqtt_inbox_dropped": stats["mqtt"].get("dropped", 0),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=100)
    p.add_argument("--rate", type=float, default=20.0)
    p.add_argument("--clients", type=int, default=5)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--connections", type=int, default=4)
    p.add_argument("--agents", type=int, default=2, help="real simulated agents answering commands")
    p.add_argument(
        "--baseline-seconds",
        type=float,
        default=5.0,
        help="how long the bare paho subscriber (the floor) listens before the WebSocket clients",
    )
    p.add_argument(
        "--phase",
        choices=("burst", "spread"),
        default="burst",
        help="burst: all robots publish in the same millisecond each tick; spread: at independent "
        "phases across the tick",
    )
    p.add_argument("--server-log", help="copy the server's log here at the end (stalls are logged with stacks)")
    p.add_argument(
        "--server-env",
        action="append",
        default=[],
        metavar="FLEET_X=VALUE",
        help="a server setting for this run (repeatable), e.g. FLEET_ROLLUP_INTERVAL_S=3600 for an A/B",
    )
    args = p.parse_args()
    if bad := [kv for kv in args.server_env if "=" not in kv]:
        p.error(f"--server-env needs NAME=VALUE, got {bad}")
    r = asyncio.run(run(args))
    ok = lambda c: "yes" if c else "NO"  # noqa: E731
    report(
        "live",
        [
            ("publish->WS p50 (ms)", f"{r['ws_p50_ms']:.1f}", "<= 5", ok(r["ws_p50_ms"] <= 5)),
            ("publish->WS p99 (ms)", f"{r['ws_p99_ms']:.1f}", "<= 30", ok(r["ws_p99_ms"] <= 30)),
            (
                "baseline: bare paho subscriber p50 / p99 (ms)",
                f"{r['baseline_p50_ms']:.1f} / {r['baseline_p99_ms']:.1f}",
                "-",
                "-",
            ),
            ("command RTT p50 (ms), lean client", f"{r['cmd_p50_ms']:.1f}", "<= 10", ok(r["cmd_p50_ms"] <= 10)),
            ("command RTT p99 (ms), lean client", f"{r['cmd_p99_ms']:.1f}", "<= 30", ok(r["cmd_p99_ms"] <= 30)),
            (
                "  p50 of its stages: HTTP in / to agent's done / ack to server / reply (ms)",
                " / ".join(f"{r['cmd_stages_p50_ms'][k]:.1f}" for k in RTT_STAGES),
                "-",
                "-",
            ),
            (
                "command RTT p50 / p99 (ms), httpx client (a script's view)",
                f"{r['cmd_httpx_p50_ms']:.1f} / {r['cmd_httpx_p99_ms']:.1f}",
                "<= 10 / 30",
                ok(r["cmd_httpx_p50_ms"] <= 10 and r["cmd_httpx_p99_ms"] <= 30),
            ),
            (
                "  p50 of its stages (ms)",
                " / ".join(f"{r['cmd_httpx_stages_p50_ms'][k]:.1f}" for k in RTT_STAGES),
                "-",
                "-",
            ),
            (
                f"server RSS at {r['robots']} robots (MB)",
                f"{r['server_rss_mb']:.0f}",
                "<= 200",
                ok(r["server_rss_mb"] <= 200),
            ),
            ("server CPU (cores)", f"{r['server_cpu_cores']:.2f}", "-", "-"),
            ("WS messages measured", str(r["ws_messages"]), "-", "-"),
            (f"  late (> {LATE_S * 1000:.0f} ms) messages", str(r["ws_late"]), "-", "-"),
        ],
        r,
    )


if __name__ == "__main__":
    main()
