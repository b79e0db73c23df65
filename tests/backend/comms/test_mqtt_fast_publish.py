"""The bridge's PUBLISH fast path against paho's own parser, on a real socket pair.

One byte stream mixes what the fast path takes (plain QoS 0/1 PUBLISH packets, retained or not, 1-3 byte
lengths) with what it must leave to paho (v5 properties, QoS 2 and its PUBREL, PINGRESP, a stray PUBACK,
a topic that is not UTF-8). Written in chunks of 1 to 1,000 bytes with a read after each, every packet is
split at every boundary. The fast path and paho alone must both deliver exactly the messages sent. A
packet not all in the buffer yet is paho's to read (on a real link: one per 64 KiB read), so the fast
path's share is checked with the whole stream in one read.
"""

from __future__ import annotations

import contextlib
import socket
from typing import Any

import pytest
from paho.mqtt.enums import CallbackAPIVersion, MQTTProtocolVersion

from backend.comms.fast_path import ChunkReadingClient, ReadBufferedSocket
from bench.rawmqtt import publish_packet

Delivered = tuple[str, bytes, bool, int, int]  # topic, payload, retain, qos, mid


def _publish(
    topic: bytes,
    payload: bytes,
    qos: int,
    mid: int,
    v5: bool,
    retain: bool = False,
    dup: bool = False,
    props: bytes = b"",
) -> bytes:
    return publish_packet(topic, payload, qos, mid, retain, dup, properties=props if v5 else None)


def _stream(v5: bool) -> tuple[bytes, list[Delivered], int]:
    """(bytes, the messages they carry in order, how many of them the fast path may take)."""
    packets: list[bytes] = []
    expected: list[Delivered] = []
    fast = 0
    # 17,000 bytes: a 3-byte remaining length
    payloads = [b"", b"{}", b'{"ts": 1.5, "seq": 7, "data": {"x": 0.25}}', bytes(range(256)) * 2, b"j" * 17_000]
    for i, payload in enumerate(payloads * 3):
        qos, retain = i % 2, i % 3 == 0
        topic = f"fleet/robot-{i}/telemetry/position"
        packets.append(_publish(topic.encode(), payload, qos, 100 + i if qos else 0, v5, retain, dup=i % 4 == 1))
        expected.append((topic, payload, retain, qos, 100 + i if qos else 0))
        fast += 1
        if i == 4:
            packets.append(b"\xd0\x00")  # PINGRESP
        if i == 6:
            packets.append(b"\x40\x02\x7f\xff")  # PUBACK for a message we never sent
        if i == 8:  # QoS 2: paho answers PUBREC and delivers on the PUBREL
            packets.append(_publish(b"fleet/q2/ack", b"two", 2, 900, v5))
            packets.append(b"\x62\x02\x03\x84")
            expected.append(("fleet/q2/ack", b"two", False, 2, 900))
        if i == 10 and v5:  # subscription identifier 2: a replica's store role
            packets.append(_publish(b"fleet/r/telemetry/imu", b"props", 1, 901, v5, props=b"\x0b\x02"))
            expected.append(("fleet/r/telemetry/imu", b"props", False, 1, 901))
        if i == 12:  # not UTF-8: left to paho, which cannot hand it to a callback as a topic
            packets.append(_publish(b"fleet/\xff\xfe/status", b"bad", 0, 0, v5))
    return b"".join(packets), expected, fast


def _client(v5: bool, fast: bool, sock: socket.socket) -> tuple[ChunkReadingClient, list[Delivered]]:
    got: list[Delivered] = []
    protocol = MQTTProtocolVersion.MQTTv5 if v5 else MQTTProtocolVersion.MQTTv311
    client = ChunkReadingClient(CallbackAPIVersion.VERSION2, client_id="fast-path-test", protocol=protocol)
    client.manual_ack_set(True)

    def on_message(c: Any, userdata: Any, msg: Any) -> None:
        # the topic that is not UTF-8 raises here: the bridge counts it as a callback error
        with contextlib.suppress(UnicodeDecodeError):
            got.append((msg.topic, bytes(msg.payload), bool(msg.retain), msg.qos, msg.mid))

    client.on_message = on_message
    if fast:
        client.fast_publish = lambda *m: got.append(m)
    sock.setblocking(False)
    client._sock = ReadBufferedSocket(sock)  # as paho's connect would, on a connected socket
    return client, got


@pytest.mark.parametrize("v5", [True, False], ids=["mqtt5", "mqtt311"])
@pytest.mark.parametrize("chunk", [1, 2, 3, 7, 64, 1000, 1 << 20])
@pytest.mark.parametrize("fast", [True, False], ids=["fast-path", "paho-only"])
def test_every_message_arrives_once_in_order_however_the_stream_is_split(v5: bool, chunk: int, fast: bool) -> None:
    data, expected, fast_count = _stream(v5)
    broker_end, client_end = socket.socketpair()
    client, got = _client(v5, fast, client_end)
    try:
        for start in range(0, len(data), chunk):
            broker_end.sendall(data[start : start + chunk])
            client.loop_read()
        for _ in range(100):  # what the last read turn left in the buffer
            client.loop_read()
        assert got == expected
        assert client.fast_taken <= fast_count if fast else client.fast_taken == 0
        if fast and chunk >= 1000:
            assert client.fast_taken > 0
    finally:
        broker_end.close()
        client_end.close()


@pytest.mark.parametrize("v5", [True, False], ids=["mqtt5", "mqtt311"])
def test_the_fast_path_takes_every_plain_publish_in_the_buffer_and_paho_the_rest(v5: bool) -> None:
    data, expected, fast_count = _stream(v5)
    assert len(data) < 65536, "the whole stream fits one read"
    broker_end, client_end = socket.socketpair()
    client, got = _client(v5, True, client_end)
    try:
        broker_end.sendall(data)
        for _ in range(20):
            client.loop_read()
        assert got == expected
        assert client.fast_taken == fast_count
    finally:
        broker_end.close()
        client_end.close()


def test_a_closed_connection_found_while_filling_the_buffer_reaches_paho() -> None:
    broker_end, client_end = socket.socketpair()
    client, got = _client(True, True, client_end)
    lost: list[object] = []
    client.on_disconnect = lambda *args: lost.append(args[3])
    try:
        broker_end.sendall(_publish(b"a/b", b"x", 1, 5, True))
        broker_end.close()
        for _ in range(5):
            client.loop_read()
        assert got == [("a/b", b"x", False, 1, 5)]
        assert client._sock is None and lost, "paho saw the end of the stream and closed its side"
    finally:
        client_end.close()


def test_the_rest_of_a_packet_paho_has_begun_is_never_parsed_as_a_new_packet() -> None:
    """A payload may itself hold the bytes of a PUBLISH. When paho holds the first part of a packet, the
    next bytes are the rest of it, even when they look like a packet of their own."""
    inner = _publish(b"fleet/x/telemetry/position", b"not a message", 1, 42, True)
    outer = _publish(b"fleet/tunnel/telemetry/raw", b"pad" + inner, 1, 77, True)
    split = outer.index(inner)
    broker_end, client_end = socket.socketpair()
    client, got = _client(True, True, client_end)
    try:
        broker_end.sendall(outer[:split])
        client.loop_read()  # paho reads what is there and waits for the rest
        broker_end.sendall(outer[split:])
        for _ in range(5):
            client.loop_read()
        assert got == [("fleet/tunnel/telemetry/raw", b"pad" + inner, False, 1, 77)]
    finally:
        broker_end.close()
        client_end.close()


def test_messages_taken_by_the_fast_path_count_as_signs_of_life_for_pahos_keepalive() -> None:
    """paho closes a link when nothing came in for a keepalive period while a PINGREQ is unanswered. A
    PINGRESP queued on the broker behind a flood arrives late; the flood itself must keep the link alive,
    so every fast-path read moves paho's clock of the last bytes received."""
    broker_end, client_end = socket.socketpair()
    client, got = _client(True, True, client_end)
    try:
        client._last_bytes_received = 0.0  # long ago
        broker_end.sendall(_publish(b"fleet/a/telemetry/position", b"{}", 1, 3, True))
        client.loop_read()
        assert got == [("fleet/a/telemetry/position", b"{}", False, 1, 3)] and client.fast_taken == 1
        assert client._last_bytes_received > 0.0
    finally:
        broker_end.close()
        client_end.close()
