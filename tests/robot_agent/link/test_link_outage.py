"""The agent's MQTT link across a real broker restart: telemetry published during the outage is buffered
and delivered in order with no gap; the motors stop the moment the link drops; a too-small buffer drops
the oldest messages and says so in the status."""

from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import orjson
import pytest

from fleet_protocol import Topics, new_command
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker, wait_for

pytestmark = pytest.mark.realtime  # wall-clock safety bounds: the realtime lane, alone (docs/testing.md)

T = Topics()


@pytest.fixture
def durable_broker(workdir: Path):
    """A broker that keeps persistent sessions across its restart (as the shipped config does)."""
    data = workdir / "mosq-data"
    data.mkdir()
    data.chmod(0o777)
    b = Broker(workdir, extra_conf=f"persistence true\npersistence_location {data}/\nuser root\n")
    b.conf.write_text(b.conf.read_text().replace("persistence false\n", ""))
    b.start()
    yield b
    b.stop()


def _positions(probe: MqttProbe, rid: str) -> list[dict]:
    topic = T.telemetry(rid, "position")
    return [orjson.loads(m.payload) for m in probe.matching(lambda m: m.topic == topic)]


def test_buffered_telemetry_survives_a_broker_restart_in_order_and_motors_stop(durable_broker, workdir):
    rid = "link-1"
    # a persistent subscriber: the broker queues for it while it is disconnected
    probe = MqttProbe(
        durable_broker.host,
        durable_broker.port,
        [T.telemetry(rid, "position"), T.ack(rid)],
        client_id="outage-probe",
        clean_session=False,
    )
    agent = AgentProcess(
        rid, durable_broker, workdir, ["--position-rate", "50", "--start-pose=0,0,0", "--buffer-size", "5000"]
    )
    agent.start()
    try:
        wait_for(lambda: len(_positions(probe, rid)) > 20, 20, what="telemetry before the outage")
        cmd = new_command("move_forward", {"speed": 1.0, "duration_s": 5.0})
        probe.publish(T.cmd(rid), orjson.dumps(cmd.model_dump(mode="json")))
        wait_for(
            lambda: any(
                orjson.loads(m.payload)["status"] == "accepted" for m in probe.matching(lambda m: m.topic == T.ack(rid))
            ),
            5,
            what="accepted",
        )
        wait_for(
            lambda: _positions(probe, rid)[-1]["data"]["x"] > _positions(probe, rid)[0]["data"]["x"] + 0.05,
            5,
            what="driving before the outage",
        )
        down_at = time.time()
        durable_broker.stop()
        time.sleep(2.0)  # the outage's length is the scenario: 100 position messages while the broker is gone
        durable_broker.start()
        up_at = time.time()
        wait_for(lambda: any(p["ts"] > up_at + 0.5 for p in _positions(probe, rid)), 20, what="after restart")
    finally:
        agent.stop()
        probe.close()
    msgs = _positions(probe, rid)
    seqs = [m["seq"] for m in msgs]
    # in order, no gap, no duplicate (QoS 1 resends may repeat: the server dedups; here we check order)
    unique = list(dict.fromkeys(seqs))
    assert unique == list(range(unique[0], unique[0] + len(unique))), "gap or reorder across the outage"
    during = [m for m in msgs if down_at + 0.3 < m["ts"] < up_at]
    assert len(during) > 50, len(during)  # published while the broker was down, delivered afterwards
    xs = [m["data"]["x"] for m in during]
    assert max(xs) - min(xs) < 1e-6, "the robot kept driving while its link was down"
    before = [m for m in msgs if m["ts"] < down_at]
    assert before[-1]["data"]["x"] > before[0]["data"]["x"] + 0.05  # it was driving before the outage
    assert math.isclose(xs[0], max(m["data"]["x"] for m in msgs if m["ts"] < up_at), abs_tol=0.02)


def _gaps(seqs: list[int]) -> list[tuple[int, int]]:
    unique = sorted(set(seqs))
    return [(a, b) for a, b in itertools.pairwise(unique) if b != a + 1]


def test_small_buffer_drops_oldest_and_reports_it(durable_broker, workdir):
    rid = "link-2"
    # every stream the simulated robot publishes (the buffer is shared by all of them)
    every_stream = T.telemetry(rid, "position").rsplit("/", 1)[0] + "/+"
    probe = MqttProbe(
        durable_broker.host,
        durable_broker.port,
        [T.status(rid), every_stream],
        client_id="small-buffer-probe",
        clean_session=False,
    )
    agent = AgentProcess(rid, durable_broker, workdir, ["--position-rate", "50", "--buffer-size", "20"])
    agent.start()
    try:
        probe.wait(lambda m: m.topic == T.status(rid) and b'"online":true' in m.payload, 20)
        wait_for(lambda: len(_positions(probe, rid)) > 10, 10, what="telemetry before the outage")
        down_at = time.time()
        durable_broker.stop()
        time.sleep(1.5)  # the outage's length is the scenario: ~75 position + ~15 imu messages into a 20-message buffer
        durable_broker.start()
        up_at = time.time()
        wait_for(lambda: any(p["ts"] > up_at + 0.5 for p in _positions(probe, rid)), 20, what="after restart")
        status = probe.wait(lambda m: m.topic == T.status(rid) and orjson.loads(m.payload)["buffer_dropped"] > 0, 10)

        def every_stream_heard_after_the_outage() -> bool:  # a drop at a stream's end shows as a gap only then
            topics = {m.topic for m in probe.matching(lambda m: "/telemetry/" in m.topic and not m.retain)}
            return all(
                any(orjson.loads(m.payload)["ts"] > up_at for m in probe.matching(lambda m, t=t: m.topic == t))
                for t in topics
            )

        wait_for(every_stream_heard_after_the_outage, 10, what="every stream after the outage")
    finally:
        agent.stop()
        probe.close()
    dropped = orjson.loads(status.payload)["buffer_dropped"]
    missing = 0
    streams = sorted({m.topic for m in probe.matching(lambda m: "/telemetry/" in m.topic)})
    assert T.telemetry(rid, "position") in streams and T.telemetry(rid, "imu") in streams, streams
    for topic in streams:
        msgs = [orjson.loads(m.payload) for m in probe.matching(lambda m, t=topic: m.topic == t)]
        gaps = _gaps([m["seq"] for m in msgs])
        # drop-oldest: one hole at the start of the outage; the newest messages before reconnecting survive
        assert len(gaps) <= 1, gaps
        if topic.endswith("/position"):
            assert len(gaps) == 1
            (last_before, first_after), by_seq = gaps[0], {m["seq"]: m for m in msgs}
            # the hole starts when the link went down (the oldest buffered messages went first) and ends
            # with messages from late in the outage (the newest were kept and delivered)
            assert by_seq[last_before]["ts"] < down_at + 0.3, by_seq[last_before]["ts"] - down_at
            assert by_seq[first_after]["ts"] > down_at + 1.0, by_seq[first_after]["ts"] - down_at
        missing += sum(b - a - 1 for a, b in gaps)
    assert dropped == missing, (dropped, missing)  # the status counts exactly what never arrived
