"""A stand-in for the server in the motion tests: it publishes the retained site and a 5 Hz heartbeat, sends
commands on a robot's cmd topic and reads back the acks, the motion stream and the positions.

Everything goes through a real Mosquitto to real agent processes; only the server is played by the test.
"""

from __future__ import annotations

import itertools
import math
import threading
import time
from typing import Any

import orjson

from fleet_protocol import (
    HEARTBEAT_PERIOD_S,
    QOS_HEARTBEAT,
    QOS_SITE,
    EStop,
    Site,
    SiteMessage,
    Topics,
    dumps,
    new_command,
    now,
)
from tests.support.mqtt import MqttProbe, Received
from tests.support.procs import wait_for

T = Topics()
POOL = [[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]
#: What the control tests run their agents with: every disturbance of the simulator on.
DISTURBED = ("--disturbances",)


def j(m: Received) -> Any:
    return orjson.loads(m.payload)


class FakeServer:
    """Plays the server's part for motion: site (retained), heartbeat (5 Hz), commands, and what comes back."""

    def __init__(self, host: str, port: int) -> None:
        self.probe = MqttProbe(host, port, [T.all_acks(), T.all_telemetry(), T.all_status()])
        self.heartbeat_on = threading.Event()
        self._stop = threading.Event()
        self.last_heartbeat_sent = 0.0
        self._seq = 0
        self._thread = threading.Thread(target=self._beat, daemon=True, name="fake-heartbeat")
        self._thread.start()

    # -- server duties ------------------------------------------------------------------------------
    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT_PERIOD_S):
            if self.heartbeat_on.is_set():
                self._seq += 1
                body = {"server_id": "test-server", "ts": now(), "seq": self._seq}
                self.probe.client.publish(T.heartbeat(), orjson.dumps(body), qos=QOS_HEARTBEAT)
                self.last_heartbeat_sent = time.time()

    def start_heartbeat(self) -> None:
        self.heartbeat_on.set()

    def stop_heartbeat(self) -> float:
        """Go silent, like a server killed with -9; returns the wall time of the last heartbeat sent."""
        self.heartbeat_on.clear()
        time.sleep(HEARTBEAT_PERIOD_S)  # let a beat in flight go out, so the returned time is the last one
        return self.last_heartbeat_sent

    def publish_site(self, version: int, site: Site | None) -> None:
        msg = SiteMessage(version=version, site=site, ts=now())
        self.probe.publish(T.site(), dumps(msg), qos=QOS_SITE, retain=True)

    def estop(self, engaged: bool) -> None:
        self.probe.publish(T.estop(), dumps(EStop(ts=now(), id=f"e-{time.time()}", engaged=engaged)), retain=True)

    def send(self, rid: str, command: str, args: dict[str, Any] | None = None, ttl_s: float = 5.0) -> str:
        cmd = new_command(command, args, ttl_s=ttl_s)
        self.probe.publish(T.cmd(rid), orjson.dumps(cmd.model_dump()))
        return cmd.id

    def send_raw_args(self, rid: str, command: str, args_json: bytes) -> str:
        """A command whose ``args`` are written by hand (NaN, 1e400, booleans ...), as a broken client might."""
        cmd = new_command(command, {})
        body = orjson.dumps(cmd.model_dump())
        assert body.endswith(b'"args":{},"ts":' + orjson.dumps(cmd.ts) + b',"ttl_s":2.0}'), body
        head = body[: body.index(b'"args":{}')]
        self.probe.publish(T.cmd(rid), head + b'"args":' + args_json + body[body.index(b',"ts":') :])
        return cmd.id

    # -- what comes back ----------------------------------------------------------------------------
    def wait_online(self, rid: str, timeout: float = 30) -> None:
        """Online, and (with the heartbeat on) subscribed long enough to have heard two heartbeats."""
        self.probe.wait(lambda m: m.topic == T.status(rid) and j(m)["online"] is True, timeout)
        if self.heartbeat_on.is_set():
            seq = self._seq
            wait_for(lambda: self._seq >= seq + 2, 5, what="two heartbeats after the robot came online")

    def final_ack(self, rid: str, cid: str, timeout: float = 60) -> dict[str, Any]:
        finals = ("done", "failed", "aborted", "rejected", "expired")
        topic, key = T.ack(rid), cid.encode()
        m = self.probe.wait(
            lambda m: m.topic == topic and key in m.payload and j(m)["id"] == cid and j(m)["status"] in finals, timeout
        )
        return dict(j(m))

    def ack(self, rid: str, cid: str, status: str, timeout: float = 10) -> dict[str, Any]:
        topic, key = T.ack(rid), cid.encode()
        m = self.probe.wait(
            lambda m: m.topic == topic and key in m.payload and j(m)["id"] == cid and j(m)["status"] == status, timeout
        )
        return dict(j(m))

    def stream(self, rid: str, stream: str, since: float = 0.0) -> list[dict[str, Any]]:
        """Envelopes (ts, seq, data) of a robot's stream received so far, sent at or after ``since``."""
        topic = T.telemetry(rid, stream)
        return [e for e in (j(m) for m in self.probe.matching(lambda m: m.topic == topic)) if e["ts"] >= since]

    def motion(self, rid: str, cid: str) -> list[dict[str, Any]]:
        return [e for e in self.stream(rid, "motion") if e["data"]["command_id"] == cid]

    def pose(self, rid: str, after: float = 0.0, timeout: float = 10) -> dict[str, Any]:
        topic = T.telemetry(rid, "position")
        m = self.probe.wait(lambda m: m.topic == topic and j(m)["ts"] > after, timeout)
        return dict(j(m)["data"])

    def wait_motion(self, rid: str, cid: str, pred: Any, timeout: float = 10) -> dict[str, Any]:
        topic = T.telemetry(rid, "motion")
        m = self.probe.wait(lambda m: m.topic == topic and j(m)["data"]["command_id"] == cid and pred(j(m)), timeout)
        return dict(j(m))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.probe.close()


def first_stop_after(motion: list[dict[str, Any]], t: float) -> float | None:
    """Wall time of the first motion report at or after ``t`` whose wheel set-points are zero."""
    for e in sorted(motion, key=lambda e: e["ts"]):
        sp = e["data"]["setpoint"]
        if e["ts"] >= t and sp["left"] == 0.0 and sp["right"] == 0.0:
            return float(e["ts"])
    return None


def moving_at(motion: list[dict[str, Any]], t: float) -> bool:
    """Whether the last report before ``t`` had the wheels turning (proves the robot could be stopped)."""
    before = [e for e in motion if e["ts"] <= t]
    if not before:
        return False
    sp = max(before, key=lambda e: e["ts"])["data"]["setpoint"]
    return bool(sp["left"] != 0.0 or sp["right"] != 0.0)


XY = list[float] | tuple[float, float]


def seg_distance(p: tuple[float, float], a: XY, b: XY) -> float:
    ax, ay = a
    sx, sy = b[0] - ax, b[1] - ay
    l2 = sx * sx + sy * sy
    t = 0.0 if l2 == 0 else max(0.0, min(1.0, ((p[0] - ax) * sx + (p[1] - ay) * sy) / l2))
    return math.hypot(p[0] - ax - t * sx, p[1] - ay - t * sy)


def polyline_distance(p: tuple[float, float], points: list[list[float]]) -> float:
    return min(seg_distance(p, a, b) for a, b in itertools.pairwise(points))
