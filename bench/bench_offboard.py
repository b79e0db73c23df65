"""An off-board controller's loop latency: through ``client.control`` (the server's control WebSocket) and
the same loop straight on the broker (paho), one after the other in one run.

Real Mosquitto, the real server, real ``fleet-agent --simulate --disturbances`` processes publishing their
position at 20 Hz. One controller per robot keeps its robot on a small circle: on each pose it computes a
velocity set-point and sends it as a ``drive``. Measured per set-point, on the agent's own clock: the pose's
``ts`` (stamped when the agent published it) -> the ``ts`` of the agent's ``accepted`` ack of that drive
command (the agent acks ``accepted`` right after the wheel set-points went to the motor driver; the
simulator's 20-50 ms actuation latency comes after that and is the motors', not the loop's).
Matching is by command id: ``client.control`` returns each set-point's command id, the broker loop makes
its own. Target (issue 17): through ``client.control``, p50 <= 15 ms and p99 <= 40 ms, 10 robots at 20 Hz.

    .venv/bin/python bench/bench_offboard.py [--robots 10] [--rate 20] [--seconds 20]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import shutil
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import orjson
import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from bench.common import cpu_seconds, forget_robots, percentile, report
from fleet_client import FleetClient
from fleet_protocol import QOS_COMMAND, Topics, new_command
from tests.support.procs import AgentProcess, Broker, ServerProcess, wait_for

T = Topics()
#: (pose ts, pose at the controller, command published by the server, command id) of each set-point
STAGES: list[tuple[float, float, float, str]] = []
RADIUS_M = 0.3
SPEED_MPS = 0.06
DEADMAN_S = 0.3


class CircleController:
    """Holds a robot on a circle of RADIUS_M (counter-clockwise) around the point left of its first pose."""

    def __init__(self) -> None:
        self.centre: tuple[float, float] | None = None

    def step(self, pose: dict[str, Any]) -> tuple[float, float]:
        x, y, yaw = float(pose["x"]), float(pose["y"]), float(pose.get("yaw") or 0.0)
        if self.centre is None:
            self.centre = (x - RADIUS_M * math.sin(yaw), y + RADIUS_M * math.cos(yaw))
        rx, ry = x - self.centre[0], y - self.centre[1]
        r = math.hypot(rx, ry) or 1e-6
        tx, ty = -ry / r, rx / r  # tangent (counter-clockwise)
        k = 3.0 * (r - RADIUS_M)
        want = math.atan2(ty - k * rx / r, tx - k * ry / r)
        err = math.atan2(math.sin(want - yaw), math.cos(want - yaw))
        return SPEED_MPS * max(0.0, math.cos(err)), max(-1.5, min(1.5, 2.5 * err))


class AckWatch:
    """The agents' acks straight from the broker: command id -> the ``accepted`` ack's ts (agent clock)."""

    def __init__(self, host: str, port: int, robots: list[str]) -> None:
        self.applied: dict[str, float] = {}
        #: command id -> (status, reason) of every ack that was not ``accepted`` (refusals, expiries)
        self.other: dict[str, tuple[str, str]] = {}
        self._lock = threading.Lock()
        self._ready = threading.Event()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="bench-offboard-acks")
        self.client.on_connect = lambda c, *_: c.subscribe([(T.ack(r), 1) for r in robots])
        self.client.on_subscribe = lambda *_: self._ready.set()
        self.client.on_message = self._on_message
        self.client.connect(host, port)
        self.client.loop_start()
        if not self._ready.wait(10):
            raise RuntimeError("ack watcher could not subscribe")

    def _on_message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        ack = orjson.loads(msg.payload)
        with self._lock:
            if ack.get("status") == "accepted":
                self.applied.setdefault(ack["id"], ack["ts"])
            elif ack.get("status") != "done":
                self.other[ack["id"]] = (str(ack.get("status")), str(ack.get("reason", ""))[:60])

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def latencies_ms(sent: list[tuple[str, float]], watch: AckWatch) -> tuple[list[float], int]:
    """(pose -> applied latencies in ms, set-points never reported applied)."""
    out, missing = [], 0
    for cid, pose_ts in sent:
        applied = watch.applied.get(cid)
        if applied is None:
            missing += 1
        else:
            out.append((applied - pose_ts) * 1000)
    return out, missing


# -- through the server ---------------------------------------------------------------------------------
async def _control_one(fleet: FleetClient, rid: str, seconds: float, sent: list[tuple[str, float]]) -> int:
    ctl_law = CircleController()
    pairs: list[tuple[int, float]] = []
    stages: list[tuple[float, float]] = []
    async with fleet.control(rid, duration_s=DEADMAN_S, client_id=f"bench-{rid}") as ctl:
        deadline = time.monotonic() + seconds
        async for pose in ctl.poses(timeout=15.0):  # a busy machine can hold a pose up for seconds
            got = time.time()
            linear, angular = ctl_law.step(pose)
            pairs.append((await ctl.drive(linear, angular), pose["ts"]))
            stages.append((pose["ts"], got))
            if time.monotonic() > deadline:
                break
        await asyncio.sleep(0.3)  # the last set-points' "sent" replies
        sent.extend((ctl.command_ids[ref], ts) for ref, ts in pairs if ref in ctl.command_ids)
        for (ref, _), (pose_ts, got) in zip(pairs, stages, strict=True):
            cid = ctl.command_ids.get(ref)
            if cid is not None:
                STAGES.append((pose_ts, got, ctl.published_at.get(cid, math.nan), cid))
        return len(pairs) - sum(1 for ref, _ in pairs if ref in ctl.command_ids) + len(ctl.errors)


def run_through_server(url: str, token: str | None, robots: list[str], seconds: float) -> tuple[list, int]:
    sent: list[tuple[str, float]] = []

    async def main() -> int:
        with FleetClient(url, token=token) as fleet:
            refused = await asyncio.gather(*(_control_one(fleet, rid, seconds, sent) for rid in robots))
        return sum(refused)

    return sent, asyncio.run(main())


# -- straight on the broker -----------------------------------------------------------------------------
def run_on_broker(host: str, port: int, robots: list[str], seconds: float) -> list[tuple[str, float]]:
    laws = {rid: CircleController() for rid in robots}
    sent: list[tuple[str, float]] = []
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="bench-offboard-direct")
    ready = threading.Event()
    running = threading.Event()
    running.set()

    def on_message(c: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        if not running.is_set():
            return
        rid = msg.topic.split("/")[1]
        env = orjson.loads(msg.payload)
        linear, angular = laws[rid].step(env["data"])
        cmd = new_command("drive", {"linear": linear, "angular": angular, "duration_s": DEADMAN_S}, ttl_s=1.0)
        c.publish(T.cmd(rid), orjson.dumps(cmd.model_dump()), qos=QOS_COMMAND)
        sent.append((cmd.id, env["ts"]))

    client.on_connect = lambda c, *_: c.subscribe([(T.telemetry(r, "position"), 0) for r in robots])
    client.on_subscribe = lambda *_: ready.set()
    client.on_message = on_message
    client.connect(host, port)
    client.loop_start()
    if not ready.wait(10):
        raise RuntimeError("broker controller could not subscribe")
    time.sleep(seconds)
    running.clear()
    for rid in robots:
        stop = new_command("stop", {})
        client.publish(T.cmd(rid), orjson.dumps(stop.model_dump()), qos=QOS_COMMAND)
    time.sleep(0.5)
    client.loop_stop()
    client.disconnect()
    return sent


@contextlib.contextmanager
def stack() -> Iterator[tuple[Broker, ServerProcess, Path]]:
    """bench.common.stack, with up to 120 s for the server to start (a busy shared machine)."""
    with tempfile.TemporaryDirectory(prefix="fleet-bench-") as tmp:
        work = Path(tmp)
        broker = Broker(work, extra_conf="max_queued_messages 1000000\n")
        broker.start()
        server = ServerProcess(broker, f"sqlite:///{work / 'fleet.db'}", work)
        try:
            server.start(wait=False)
            server.wait_ready(120)
            yield broker, server, work
            forget_robots(server)
        finally:
            server.stop()
            broker.stop()


def _summary(values: list[float]) -> str:
    return f"{percentile(values, 50):.1f} / {percentile(values, 99):.1f}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--rate", type=float, default=20.0, help="position (and so control) rate, Hz")
    p.add_argument("--seconds", type=float, default=20.0, help="per way")
    args = p.parse_args()
    with stack() as (broker, server, work):
        robots = [f"ob{i:02d}" for i in range(args.robots)]
        agents = []
        for i, rid in enumerate(robots):
            a = 2 * math.pi * i / args.robots
            pose = f"--start-pose={1.2 * math.cos(a):.2f},{1.2 * math.sin(a):.2f},{a + math.pi / 2:.2f}"
            agents.append(AgentProcess(rid, broker, work, ["--disturbances", "--position-rate", str(args.rate), pose]))
            agents[-1].start()
        watch = AckWatch(broker.host, broker.port, robots)
        try:
            with server.client() as http:
                wait_for(
                    lambda: (
                        sum(1 for r in http.get("/api/robots").json() if r["online"] and r["position"]) == args.robots
                    ),
                    60,
                    what="robots online with a fix",
                )
            time.sleep(1.0)
            assert server.proc is not None
            server_pid = server.proc.pid
            cpu0 = cpu_seconds(server_pid)
            t0 = time.monotonic()
            try:
                via_server, refused = run_through_server(server.base_url, server.token, robots, args.seconds)
            except Exception:
                kept = Path(tempfile.mkdtemp(prefix="offboard-failed-"))
                shutil.copytree(work, kept, dirs_exist_ok=True)
                print(f"the run failed: its logs are kept in {kept}", file=sys.stderr)
                raise
            server_cpu = (cpu_seconds(server_pid) - cpu0) / (time.monotonic() - t0)
            time.sleep(1.0)
            direct = run_on_broker(broker.host, broker.port, robots, args.seconds)
            time.sleep(0.5)
        finally:
            watch.close()
            for a in agents:
                a.stop()
    lat_server, miss_server = latencies_ms(via_server, watch)
    lat_direct, miss_direct = latencies_ms(direct, watch)
    for way, sent in (("server", via_server), ("broker", direct)):
        why = Counter(
            watch.other.get(cid, ("no ack", ""))[0] + " " + watch.other.get(cid, ("", ""))[1].split(" (")[0]
            for cid, _ in sent
            if cid not in watch.applied
        )
        if why:
            print(f"not applied ({way}): " + ", ".join(f"{n} x {what.strip()}" for what, n in why.most_common(4)))
    to_client = [(got - ts) * 1000 for ts, got, _, _ in STAGES]
    to_publish = [(pub - got) * 1000 for _, got, pub, _ in STAGES]
    to_agent = [(watch.applied[cid] - pub) * 1000 for _, _, pub, cid in STAGES if cid in watch.applied]
    ok = percentile(lat_server, 50) <= 15 and percentile(lat_server, 99) <= 40
    rows = [
        ("client.control: pose -> applied p50 / p99 ms", _summary(lat_server), "<= 15 / <= 40", "yes" if ok else "NO"),
        ("  stage: pose -> controller p50 / p99 ms", _summary(to_client), "", ""),
        ("  stage: controller -> server published", _summary(to_publish), "", ""),
        ("  stage: server published -> applied", _summary(to_agent), "", ""),
        ("straight on the broker (paho) p50 / p99 ms", _summary(lat_direct), "-", ""),
        ("set-points matched (server / broker)", f"{len(lat_server)} / {len(lat_direct)}", "", ""),
        ("not applied or refused (server / broker)", f"{miss_server + refused} / {miss_direct}", "0 / 0", ""),
    ]
    report(
        "offboard",
        rows,
        {
            "robots": args.robots,
            "rate_hz": args.rate,
            "seconds": args.seconds,
            "server_p50_ms": percentile(lat_server, 50),
            "server_p99_ms": percentile(lat_server, 99),
            "server_max_ms": max(lat_server, default=math.nan),
            "broker_p50_ms": percentile(lat_direct, 50),
            "broker_p99_ms": percentile(lat_direct, 99),
            "broker_max_ms": max(lat_direct, default=math.nan),
            "server_setpoints": len(lat_server),
            "broker_setpoints": len(lat_direct),
            "server_missing": miss_server + refused,
            "broker_missing": miss_direct,
            "server_cpu_cores": round(server_cpu, 2),
            "target_met": ok,
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
