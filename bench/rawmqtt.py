"""A cheap MQTT 3.1.1 publisher for load generation: raw packets on a plain socket.

A paho publisher in Python tops out at a few thousand QoS 1 messages/s and would measure itself. Here a
PUBLISH is a few bytes of header around a pre-encoded payload, written in batches; for QoS 1 a reader
thread counts PUBACKs so the sender keeps at most ``window`` messages in flight (the broker's
``max_inflight_messages`` and paho's 65,535 packet-id limit both stay out of the way).
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time


def remaining_length(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n % 128, n // 128
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _utf8(s: str | bytes) -> bytes:
    b = s.encode() if isinstance(s, str) else s
    return struct.pack(">H", len(b)) + b


def connect_packet(client_id: str, keepalive: int = 60, will: tuple[str, bytes] | None = None) -> bytes:
    flags = 0x02  # clean session
    payload = _utf8(client_id)
    if will is not None:
        flags |= 0x04 | 0x20 | (1 << 3)  # will flag, will retain, will QoS 1
        payload += _utf8(will[0]) + struct.pack(">H", len(will[1])) + will[1]
    var = _utf8("MQTT") + bytes([4, flags]) + struct.pack(">H", keepalive)
    body = var + payload
    return bytes([0x10]) + remaining_length(len(body)) + body


def publish_packet(
    topic: str | bytes,
    payload: bytes,
    qos: int = 0,
    packet_id: int = 0,
    retain: bool = False,
    dup: bool = False,
    properties: bytes | None = None,
) -> bytes:
    """A PUBLISH: MQTT 3.1.1 when ``properties`` is None, else MQTT 5 with that property block (b"": none).
    A topic given as bytes is sent as it is (even when it is not UTF-8)."""
    header = 0x30 | (0x08 if dup else 0) | (qos << 1) | (1 if retain else 0)
    body = _utf8(topic) + (struct.pack(">H", packet_id) if qos else b"")
    if properties is not None:
        body += remaining_length(len(properties)) + properties
    body += payload
    return bytes([header]) + remaining_length(len(body)) + body


class RawPublisher:
    """One TCP connection. ``publish`` is cheap; QoS 1 is flow-controlled by a PUBACK-counting thread."""

    def __init__(
        self, host: str, port: int, client_id: str, window: int = 500, will: tuple[str, bytes] | None = None
    ) -> None:
        self.sock = socket.create_connection((host, port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock.sendall(connect_packet(client_id, will=will))
        connack = self._read_exact(4)
        if connack[0] != 0x20 or connack[3] != 0:
            raise ConnectionError(f"CONNACK refused: {connack!r}")
        self.window = window
        self.sent_qos1 = 0
        self.acked = 0
        self._next_id = 0
        self._cond = threading.Condition()
        self._closed = False
        self._reader = threading.Thread(target=self._read_acks, daemon=True, name=f"raw-{client_id}")
        self._reader.start()

    def _read_exact(self, n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = self.sock.recv(n - len(buf))
            if not chunk:
                raise ConnectionError("broker closed the connection")
            buf += chunk
        return buf

    def _read_acks(self) -> None:
        pending = b""
        try:
            while not self._closed:
                chunk = self.sock.recv(65536)
                if not chunk:
                    return
                pending += chunk
                acks = 0
                while len(pending) >= 2:
                    length = pending[1]  # PUBACK/PINGRESP/SUBACK here are all short
                    if len(pending) < 2 + length:
                        break
                    if pending[0] == 0x40:
                        acks += 1
                    pending = pending[2 + length :]
                if acks:
                    with self._cond:
                        self.acked += acks
                        self._cond.notify_all()
        except OSError:
            return

    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> None:
        if qos == 0:
            self.sock.sendall(publish_packet(topic, payload, 0, retain=retain))
            return
        with self._cond:
            while self.sent_qos1 - self.acked >= self.window:
                if not self._cond.wait(5):
                    raise TimeoutError("no PUBACK for 5 s")
        self._next_id = self._next_id % 65535 + 1
        self.sent_qos1 += 1
        self.sock.sendall(publish_packet(topic, payload, 1, self._next_id, retain))

    def send_many(self, packets: list[bytes]) -> None:
        """QoS 0 packets (from :func:`publish_packet`) in one write."""
        self.sock.sendall(b"".join(packets))

    def drain(self, timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        with self._cond:
            while self.acked < self.sent_qos1:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def close(self) -> None:
        self._closed = True
        with contextlib.suppress(OSError):
            self.sock.sendall(b"\xe0\x00")  # DISCONNECT: no Last Will
        self.sock.close()
        self._reader.join(2)
