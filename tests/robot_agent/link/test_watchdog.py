"""A frozen link (Wi-Fi dropout: the socket stays open, nothing arrives) stops a driving robot within half
a second, long before TCP or MQTT keepalive notice; the broker's Last Will then marks it offline."""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import orjson
import pytest

from fleet_protocol import LINK_SILENCE_S, Topics, new_command
from robot_agent.link.watchdog import LinkWatchdog
from tests.support.procs import VENV_BIN, ManagedProcess, base_env, wait_for
from tests.support.proxy import FreezableProxy

pytestmark = pytest.mark.realtime  # wall-clock safety bounds: the realtime lane, alone (docs/testing.md)

T = Topics()


def test_watchdog_trips_only_while_driving_and_silent() -> None:
    now = [0.0]
    driving = [False]
    sent: list[bytes] = []
    trips: list[str] = []
    wd = LinkWatchdog(lambda: driving[0], sent.append, trips.append, period_s=0.1, silence_s=0.35, clock=lambda: now[0])
    for _ in range(10):  # idle: nothing sent, nothing tripped
        now[0] += 0.1
        wd.tick()
    assert sent == [] and trips == []
    driving[0] = True
    for _ in range(10):  # driving with echoes: pings go out, no trip
        now[0] += 0.1
        wd.tick()
        if sent:
            wd.on_echo(sent[-1])
    assert len(sent) == 10 and trips == []
    for _ in range(5):  # echoes stop
        now[0] += 0.1
        wd.tick()
    assert trips == ["link silent"] and wd.trips == 1
    wd.on_echo(b"garbage")  # malformed echo is ignored
    assert wd.trips == 1


def test_frozen_link_stops_the_motors_within_half_a_second(broker, mqtt_probe, workdir: Path) -> None:
    proxy = FreezableProxy(broker.host, broker.port)
    probe = mqtt_probe(T.telemetry("wd-1", "position"), T.status("wd-1"), T.ack("wd-1"))
    agent = ManagedProcess(
        "agent-wd-1",
        [
            str(VENV_BIN / "fleet-agent"),
            "--robot-id",
            "wd-1",
            "--simulate",
            "--broker",
            proxy.url,
            "--keepalive",
            "2",
            "--position-rate",
            "50",
            "--start-pose=0,0,0",
        ],
        base_env(),
        workdir,
    )
    agent.start()
    try:
        probe.wait(lambda m: m.topic == T.status("wd-1") and b'"online":true' in m.payload, 20)
        cmd = new_command("move_forward", {"speed": 1.0, "duration_s": 5.0})
        probe.publish(T.cmd("wd-1"), orjson.dumps(cmd.model_dump(mode="json")))
        probe.wait(lambda m: m.topic == T.ack("wd-1") and b'"accepted"' in m.payload, 5)
        # driving when the link freezes: a position under way has reached us
        probe.wait(
            lambda m: m.topic == T.telemetry("wd-1", "position") and orjson.loads(m.payload)["data"]["x"] > 0.01, 5
        )
        frozen_at = time.time()
        proxy.freeze()
        # a command sent during the outage (ttl 1 s) must never run once the link is back
        late = new_command("move_forward", {"speed": 1.0, "duration_s": 5.0}, ttl_s=1.0)
        probe.publish(T.cmd("wd-1"), orjson.dumps(late.model_dump(mode="json")))
        # the broker notices the silence after 1.5 x keepalive and publishes the Last Will
        probe.wait(lambda m: m.topic == T.status("wd-1") and b'"online":false' in m.payload, 10)
        wait_for(lambda: time.time() > late.ts + late.ttl_s, 5, what="the late command's ttl")  # still frozen
        thawed_at = time.time()
        proxy.thaw()  # the agent reconnects (or its TCP connection recovers) and delivers what it buffered
        wait_for(
            lambda: any(
                orjson.loads(m.payload)["ts"] > frozen_at + 2.5
                for m in probe.matching(lambda m: m.topic == T.telemetry("wd-1", "position"))
            ),
            30,
            what="telemetry from after the freeze",
        )
    finally:
        agent.stop()
        proxy.close()
    topic = T.telemetry("wd-1", "position")
    pts = sorted((orjson.loads(m.payload) for m in probe.matching(lambda m: m.topic == topic)), key=lambda p: p["ts"])
    moving = [p for a, p in itertools.pairwise(pts) if p["data"]["x"] - a["data"]["x"] > 1e-5]
    stopped_moving_at = max(p["ts"] for p in moving)
    # watchdog window (0.35 s) + one ping period + the wheels' spin-down
    assert stopped_moving_at - frozen_at < 0.5 + 0.1, stopped_moving_at - frozen_at
    assert stopped_moving_at - frozen_at > LINK_SILENCE_S - 0.1  # it drove until the link really went silent
    acks = [orjson.loads(m.payload) for m in probe.matching(lambda m: m.topic == T.ack("wd-1"))]
    assert any(a["id"] == cmd.id and a["status"] == "done" and a["reason"] == "link silent" for a in acks), acks
    # the command from the outage: never accepted, and the robot never moved after the link came back
    assert all(a["status"] in ("expired", "rejected") for a in acks if a["id"] == late.id), acks
    assert not [p for a, p in itertools.pairwise(pts) if p["ts"] > thawed_at and p["data"]["x"] - a["data"]["x"] > 1e-5]
