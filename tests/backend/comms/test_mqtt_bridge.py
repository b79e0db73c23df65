"""The server's MQTT bridge against a real Mosquitto: paho on the event loop (no network thread),
reconnects, acks handed over from another thread, and a clean DISCONNECT on stop."""

from __future__ import annotations

import asyncio
import functools
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Awaitable, Callable
from pathlib import Path

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from backend.comms.mqtt_bridge import AckToken, InboundMessage, MqttBridge, Subscription
from tests.support.mqtt import MqttProbe
from tests.support.procs import Broker, wait_until


def _run(scenario: Callable[[], Awaitable[None]]) -> None:
    """Run the scenario on a fresh loop and check the bridge left no thread of its own behind."""
    before = set(threading.enumerate())
    asyncio.run(scenario())  # type: ignore[arg-type]
    left = [t for t in threading.enumerate() if t not in before and t.is_alive()]
    assert left == [], f"threads left behind: {left}"


def test_messages_are_handled_on_the_loop_thread_and_stop_disconnects_cleanly(broker: Broker) -> None:
    probe = MqttProbe(broker.host, broker.port, ["out/#"])
    got: list[tuple[InboundMessage, int]] = []

    async def scenario() -> None:
        loop_thread = threading.get_ident()
        bridge = MqttBridge(
            broker.url,
            [Subscription("in/#", 1)],
            lambda batch: got.extend((m, threading.get_ident()) for m in batch),
            client_id="bridge-loop-test",
        )
        bridge.start(asyncio.get_running_loop())
        try:
            await wait_until(lambda: bridge.connected)
            assert not [t for t in threading.enumerate() if t.name == "paho-mqtt-client-bridge-loop-test"]
            await asyncio.to_thread(probe.publish, "in/a", b"one", 1)
            await asyncio.to_thread(probe.publish, "in/b", b"two", 0)
            await wait_until(lambda: len(got) == 2)
            assert sorted(m.payload for m, _ in got) == [b"one", b"two"]
            assert {thread for _, thread in got} == {loop_thread}
            assert bridge.stats()["parsed_without_paho"] == 2  # plain PUBLISH packets skip paho's parser
            assert bridge.publish("out/x", b"reply", qos=1)
            await asyncio.to_thread(probe.wait, lambda r: r.topic == "out/x" and r.payload == b"reply")
        finally:
            await bridge.stop()
        assert not bridge.connected
        assert bridge.stats()["callback_errors"] == 0

    try:
        _run(scenario)
    finally:
        probe.close()
    # a DISCONNECT packet, not a dropped socket (the broker would publish a Last Will for one)
    log = broker.log.read_text()
    assert "Client bridge-loop-test disconnected" in log, log[-2000:]


def test_reconnects_when_the_broker_comes_up_late_and_after_a_restart(workdir: Path) -> None:
    broker = Broker(workdir)  # not started yet
    got: list[bytes] = []
    changes: list[bool] = []

    async def scenario() -> None:
        bridge = MqttBridge(
            broker.url,
            [Subscription("in/#", 1)],
            lambda batch: got.extend(m.payload for m in batch),
            on_connection_change=changes.append,
            client_id="bridge-reconnect-test",
        )
        bridge.start(asyncio.get_running_loop())
        try:
            await wait_until(lambda: bridge.connect_failures >= 1)
            assert not bridge.connected
            await asyncio.to_thread(broker.start)
            await wait_until(lambda: bridge.connected, timeout=15)
            await asyncio.to_thread(_publish_once, broker, "in/first", b"1")
            await wait_until(lambda: got == [b"1"])

            await asyncio.to_thread(broker.kill)
            await wait_until(lambda: not bridge.connected)
            await asyncio.to_thread(broker.start)  # same port, no persistence: subscriptions must be re-made
            await wait_until(lambda: bridge.connected, timeout=15)
            await asyncio.to_thread(_publish_once, broker, "in/second", b"2")
            await wait_until(lambda: got == [b"1", b"2"])
        finally:
            await bridge.stop()
        assert changes[:3] == [True, False, True]

    try:
        _run(scenario)
    finally:
        broker.stop()


def _publish_once(broker: Broker, topic: str, payload: bytes) -> None:
    probe = MqttProbe(broker.host, broker.port)
    try:
        probe.publish(topic, payload, 1)
    finally:
        probe.close()


def _session_redelivers(broker: Broker, ack_from_thread: bool) -> list[bytes]:
    """Receive three QoS 1 messages, PUBACK them (from a worker thread, as the DB writer does) or not,
    reconnect with the same persistent session and return what the broker delivers again."""
    first: list[bytes] = []
    again: list[bytes] = []

    async def scenario() -> None:
        acker: list[threading.Thread] = []

        def on_ack_marker(tokens: list[AckToken]) -> None:
            if ack_from_thread and tokens:
                worker = threading.Thread(target=bridge.ack, args=(tokens,))
                worker.start()
                acker.append(worker)

        bridge = MqttBridge(
            broker.url,
            [Subscription("in/#", 1)],
            lambda b: first.extend(m.payload for m in b),
            client_id="bridge-ack-test",
            on_ack_marker=on_ack_marker,
        )
        bridge.start(asyncio.get_running_loop())
        await wait_until(lambda: bridge.connected)
        for i in range(3):
            await asyncio.to_thread(_publish_once, broker, f"in/{i}", str(i).encode())
        await wait_until(lambda: len(first) == 3)
        for worker in acker:
            worker.join(5)
        await wait_until(lambda: bridge.acks_sent == (3 if ack_from_thread else 0), timeout=5)
        await bridge.stop()  # writes what is queued, the PUBACKs first, then DISCONNECT (one ordered socket)

        second = MqttBridge(
            broker.url,
            [Subscription("in/#", 1)],
            lambda b: again.extend(m.payload for m in b),
            client_id="bridge-ack-test",
        )
        second.start(asyncio.get_running_loop())
        await wait_until(lambda: second.connected)
        # a resumed session delivers what was not acknowledged first, ahead of anything published now:
        # once a message published after the reconnect is here, every redelivery would be here too
        await asyncio.to_thread(_publish_once, broker, "in/marker", b"marker")
        await wait_until(lambda: b"marker" in again, timeout=5)
        await second.stop()

    _run(scenario)
    assert sorted(first) == [b"0", b"1", b"2"]
    return sorted(p for p in again if p != b"marker")


def test_acks_sent_from_another_thread_end_the_redelivery(broker: Broker) -> None:
    assert _session_redelivers(broker, ack_from_thread=False) == [b"0", b"1", b"2"]
    assert _session_redelivers(broker, ack_from_thread=True) == []


def _private_ca(directory: Path) -> tuple[Path, Path, Path]:
    """A CA and a certificate for 127.0.0.1 signed by it (openssl CLI), readable by Mosquitto's user:
    the broker loads its key after dropping root."""
    directory.chmod(0o755)
    ca_key, ca_crt = directory / "ca.key", directory / "ca.crt"
    key, csr, crt = directory / "server.key", directory / "server.csr", directory / "server.crt"
    ext = directory / "ext.cnf"
    ext.write_text("subjectAltName=IP:127.0.0.1\n")
    run = functools.partial(subprocess.run, check=True, capture_output=True)
    run(
        [
            "openssl",
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-keyout",
            ca_key,
            "-out",
            ca_crt,
            "-days",
            "2",
            "-subj",
            "/CN=fleet-test-ca",
        ]
    )
    run(["openssl", "req", "-newkey", "rsa:2048", "-nodes", "-keyout", key, "-out", csr, "-subj", "/CN=127.0.0.1"])
    run(
        [
            "openssl",
            "x509",
            "-req",
            "-in",
            csr,
            "-CA",
            ca_crt,
            "-CAkey",
            ca_key,
            "-CAcreateserial",
            "-out",
            crt,
            "-days",
            "2",
            "-extfile",
            ext,
        ]
    )
    key.chmod(0o644)
    return ca_crt, crt, key


def test_tls_broker_with_a_private_ca(monkeypatch, tmp_path: Path) -> None:
    """mqtts://: the handshake runs in the executor, then the loop reads the SSL socket (messages of 200 kB
    span many TLS records) and acknowledges every message."""
    certs = Path(tempfile.mkdtemp(prefix="fleet-tls-"))
    try:
        ca_crt, crt, key = _private_ca(certs)
        broker = Broker(tmp_path, extra_conf=f"cafile {ca_crt}\ncertfile {crt}\nkeyfile {key}\n")
        broker.start()
        monkeypatch.setenv("SSL_CERT_FILE", str(ca_crt))  # the server trusts the system store (docs/security.md)
        got: list[bytes] = []

        async def scenario() -> None:
            bridge = MqttBridge(
                f"mqtts://127.0.0.1:{broker.port}",
                [Subscription("in/#", 1)],
                lambda batch: got.extend(m.payload for m in batch),
                client_id="bridge-tls-test",
            )
            bridge.start(asyncio.get_running_loop())
            try:
                await wait_until(lambda: bridge.connected)
                await asyncio.to_thread(_publish_tls, broker.port, ca_crt)
                await wait_until(lambda: len(got) == 50)
                assert [len(p) for p in got] == [200_000 if i % 10 == 0 else 10 for i in range(50)]
                assert bridge.stats()["acks_sent"] == 50
            finally:
                await bridge.stop()
            assert bridge.stats()["callback_errors"] == 0

        try:
            _run(scenario)
        finally:
            broker.stop()
    finally:
        shutil.rmtree(certs, ignore_errors=True)


def _publish_tls(port: int, ca_crt: Path) -> None:
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="tls-publisher")
    client.tls_set(ca_certs=str(ca_crt))
    client.connect("127.0.0.1", port)
    client.loop_start()
    try:
        infos = [client.publish("in/x", b"x" * (200_000 if i % 10 == 0 else 10), qos=1) for i in range(50)]
        for info in infos:
            info.wait_for_publish(10)
    finally:
        client.disconnect()
        client.loop_stop()


def test_a_flood_read_in_turns_is_read_to_the_end(broker: Broker) -> None:
    """The loop parses at most READ_TURN_PACKETS packets per socket read and then lets other work run; the
    rest of the 64 kB chunk is already in the bridge's buffer, where select() does not see it. The bridge
    must read on by itself, or the last messages of a flood wait for the next byte from the broker."""
    got: list[bytes] = []

    async def scenario() -> None:
        bridge = MqttBridge(
            broker.url,
            [Subscription("in/#", 0)],
            lambda b: got.extend(m.payload for m in b),
            client_id="bridge-flood-test",
        )
        bridge.start(asyncio.get_running_loop())
        try:
            await wait_until(lambda: bridge.connected)
            publisher = threading.Thread(target=_flood, args=(broker, 5000))
            publisher.start()
            publisher.join(30)  # the loop is blocked meanwhile: the broker's messages pile up in the socket
            # well before the keepalive (10 s), whose PINGRESP would wake a stuck reader
            await wait_until(lambda: len(got) == 5000, timeout=4)
            assert got == [str(i).encode() for i in range(5000)]
        finally:
            await bridge.stop()

    _run(scenario)


def _flood(broker: Broker, count: int) -> None:
    probe = MqttProbe(broker.host, broker.port)
    try:
        for i in range(count):
            probe.client.publish("in/f", str(i).encode(), qos=0)
        probe.publish("sync/f", b"", 1)  # QoS 1 round trip: everything before it left the probe
    finally:
        probe.close()
