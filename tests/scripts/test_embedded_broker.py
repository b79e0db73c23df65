"""The demo's fallback broker (scripts/embedded_broker.py, amqtt) does what the fleet relies on, checked with
paho, the client the agent and the server use: connect, QoS 1, retained messages, Last Will, clean stop."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest

from tests.support.mqtt import MqttProbe
from tests.support.procs import base_env, free_port, wait_for, wait_port

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def embedded_broker(tmp_path: Path) -> Iterator[int]:
    port = free_port()
    log = open(tmp_path / "broker.log", "wb")  # noqa: SIM115 - closed below
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "scripts" / "embedded_broker.py"), "--host", "127.0.0.1", "--port", str(port)],
        stdout=log,
        stderr=subprocess.STDOUT,
        env=base_env(),
    )
    try:
        wait_port(port, 20)
        yield port
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0, (tmp_path / "broker.log").read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
        log.close()


def _client(port: int, name: str) -> mqtt.Client:
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"{name}-{uuid.uuid4().hex[:6]}")
    c.connect("127.0.0.1", port, keepalive=10)
    c.loop_start()
    return c


def _stop(c: mqtt.Client) -> None:
    c.disconnect()
    c.loop_stop()


def test_qos1_and_retained_messages(embedded_broker: int) -> None:
    got: list[tuple[str, bytes, int, bool]] = []
    arrived = threading.Event()

    def on_message(_c: object, _u: object, m: mqtt.MQTTMessage) -> None:
        got.append((m.topic, bytes(m.payload), m.qos, bool(m.retain)))
        arrived.set()

    sub = _client(embedded_broker, "sub")
    sub.on_message = on_message
    subacked = threading.Event()
    sub.on_subscribe = lambda *_args: subacked.set()
    sub.subscribe("fleet/+/telemetry/+", qos=1)
    pub = _client(embedded_broker, "pub")
    try:
        wait_for(lambda: sub.is_connected() and pub.is_connected(), what="connections")
        assert subacked.wait(10), "no SUBACK"  # the broker holds the subscription before the publish
        for info in (
            pub.publish("fleet/r1/status", b'{"online": true}', qos=1, retain=True),
            pub.publish("fleet/r1/telemetry/position", b'{"seq": 1}', qos=1),
        ):
            info.wait_for_publish(5)
            assert info.is_published()  # PUBACK: the broker took the QoS 1 message
        assert arrived.wait(10)
        assert got == [("fleet/r1/telemetry/position", b'{"seq": 1}', 1, False)]
    finally:
        _stop(pub)
        _stop(sub)
    # a client that subscribes later gets the retained status, flagged retained
    late = MqttProbe("127.0.0.1", embedded_broker, ["fleet/+/status"])
    try:
        m = late.wait(lambda m: m.topic == "fleet/r1/status")
        assert m.retain and m.payload == b'{"online": true}'
    finally:
        late.close()


def test_last_will_is_published_retained_when_a_client_vanishes(embedded_broker: int) -> None:
    watcher = MqttProbe("127.0.0.1", embedded_broker, ["fleet/+/status"])
    try:
        robot = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"robot-{uuid.uuid4().hex[:6]}")
        robot.will_set("fleet/r2/status", b'{"online": false}', qos=1, retain=True)
        robot.connect("127.0.0.1", embedded_broker, keepalive=5)
        robot.loop_start()
        robot.publish("fleet/r2/status", b'{"online": true}', qos=1, retain=True).wait_for_publish(5)
        watcher.wait(lambda m: m.topic == "fleet/r2/status" and m.payload == b'{"online": true}')
        robot.loop_stop()
        sock = robot.socket()
        assert sock is not None
        sock.close()  # the link drops without DISCONNECT: the broker publishes the will
        watcher.wait(lambda m: m.topic == "fleet/r2/status" and m.payload == b'{"online": false}', 15)
    finally:
        watcher.close()
    late = MqttProbe("127.0.0.1", embedded_broker, ["fleet/r2/status"])
    try:
        assert late.wait(lambda m: m.topic == "fleet/r2/status").payload == b'{"online": false}'
    finally:
        late.close()
