"""The PUBLISH fast path: paho's client reading its socket in 64 KiB chunks and taking plain PUBLISH
packets straight from that buffer, and PUBACKs queued many at a time.

paho 2.x reads every packet with three or more ``recv()`` calls and builds an ``MQTTMessage`` and a
``Properties`` object per message (29 us of Python each, against about 1 us here), and queues each 4-byte
PUBACK on its own. At 10,000 msg/s that was most of the server's ingest CPU. The price: this code uses
paho's private members (:data:`PAHO_PRIVATE_MEMBERS`), so it runs only on the paho release it was tested
with (:data:`TESTED_PAHO_VERSION`, the version pyproject pins) and only when those members are there;
otherwise :func:`choose_fast_path` says why and the bridge lets paho parse every packet
(``FLEET_MQTT_FAST_PATH=false`` does the same on purpose). tests/backend/comms/test_mqtt_fast_publish.py
proves the parser against paho's own on every split of a mixed stream, and fails when a member changes.
"""

from __future__ import annotations

import inspect
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import paho.mqtt
import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode

#: the paho release the fast path is proven against (pyproject pins the same)
TESTED_PAHO_VERSION = "2.2.0"
#: MQTT packets parsed per readable-socket callback; the rest wait one loop turn (HTTP and WebSocket work
#: in between) instead of holding the loop for a whole flood
READ_TURN_PACKETS = 500

#: paho's private methods the fast path calls or overrides: name -> parameter names (self first)
PAHO_PRIVATE_METHODS: dict[str, tuple[str, ...]] = {
    "_create_socket": ("self",),
    "_packet_queue": ("self", "command", "packet", "mid", "qos", "info"),
}
#: paho's private attributes of a client instance it reads or writes: name -> expected type
PAHO_PRIVATE_ATTRIBUTES: dict[str, type | tuple[type, ...]] = {
    "_in_packet": dict,  # its "command" is 0 between packets
    "_sock": (type(None), socket.socket),
    "_protocol": int,
    "_msgtime_mutex": type(threading.Lock()),
    "_last_bytes_received": float,  # paho's keepalive clock
}
#: every private member, for the log and the test
PAHO_PRIVATE_MEMBERS = (*PAHO_PRIVATE_METHODS, *PAHO_PRIVATE_ATTRIBUTES)

_PUBACK = 0x40
#: PUBACK fixed header with remaining length 2: packet id only (MQTT 3.1.1; in v5 it means "Success")
_PUBACK_HEADER = bytes([_PUBACK, 2])

#: takes (topic, payload, retain, qos, mid) of a PUBLISH parsed without paho
PublishSink = Callable[[str, bytes, bool, int, int], None]


def paho_member_changes() -> list[str]:
    """What differs from the private members the fast path was written against (empty: nothing)."""
    problems: list[str] = []
    for name, params in PAHO_PRIVATE_METHODS.items():
        member = getattr(mqtt.Client, name, None)
        if not callable(member):
            problems.append(f"paho Client.{name} is missing")
            continue
        found = tuple(inspect.signature(member).parameters)
        if found != params:
            problems.append(f"paho Client.{name}{found} is not {params}")
    client = mqtt.Client(CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5)
    for name, kind in PAHO_PRIVATE_ATTRIBUTES.items():
        if not hasattr(client, name):
            problems.append(f"paho Client.{name} is missing")
        elif not isinstance(getattr(client, name), kind):
            problems.append(f"paho Client.{name} is a {type(getattr(client, name)).__name__}")
    in_packet = getattr(client, "_in_packet", None)
    if isinstance(in_packet, dict) and in_packet.get("command") != 0:
        problems.append("paho Client._in_packet has no 'command' 0 between packets")
    return problems


def choose_fast_path(wanted: bool) -> tuple[bool, str]:
    """(use it, why): on only when wanted, on the tested paho release, with its private members intact."""
    paho_version = str(getattr(paho.mqtt, "__version__", "unknown"))
    if not wanted:
        return False, "off (FLEET_MQTT_FAST_PATH=false): paho parses every packet"
    if paho_version != TESTED_PAHO_VERSION:
        return False, (
            f"off: paho-mqtt {paho_version} is not the tested {TESTED_PAHO_VERSION}; paho parses every packet"
        )
    problems = paho_member_changes()
    if problems:
        return False, "off: " + "; ".join(problems) + "; paho parses every packet"
    return True, f"on (paho-mqtt {paho_version})"


class ReadBufferedSocket:
    """A plain TCP socket read in 64 KiB chunks. Small reads are served from memory, and ``pending()``
    (what paho asks a TLS socket) tells paho to read on without waiting in select().
    :meth:`take_publishes` parses plain PUBLISH packets straight from the buffer."""

    __slots__ = ("_buf", "_eof", "_error", "_pos", "_sock")

    def __init__(self, sock: socket.socket) -> None:
        self._sock = sock
        self._buf = b""
        self._pos = 0
        self._eof = False
        self._error: OSError | None = None

    def recv(self, bufsize: int) -> bytes:
        avail = len(self._buf) - self._pos
        if avail == 0:
            if self._error is not None:  # met by fill(): paho reports it as it would have
                error, self._error = self._error, None
                raise error
            if self._eof:
                return b""  # the peer closed (seen by fill()): paho sees it now
            data = self._sock.recv(max(bufsize, 65536))  # BlockingIOError when nothing is there
            if len(data) <= bufsize:
                return data  # b"" at EOF
            self._buf, self._pos, avail = data, 0, len(data)
        end = self._pos + min(bufsize, avail)
        out = self._buf[self._pos : end]
        if end == len(self._buf):
            self._buf, self._pos = b"", 0
        else:
            self._pos = end
        return out

    def pending(self) -> int:
        return len(self._buf) - self._pos

    def fill(self) -> bool:
        """Read what the socket has when the buffer is empty; False when there is nothing to read now.
        An error or EOF is kept for paho's next ``recv`` (it reports a lost connection, as it always has)."""
        if self._pos < len(self._buf) or self._eof or self._error is not None:
            return True
        try:
            data = self._sock.recv(65536)
        except BlockingIOError:
            return False
        except OSError as exc:
            self._error = exc
            return True
        if data:
            self._buf, self._pos = data, 0
        else:
            self._eof = True
        return True

    def take_publishes(self, sink: PublishSink, limit: int, v5: bool) -> int:
        """Hand complete QoS 0/1 PUBLISH packets without properties at the head of the buffer to ``sink``;
        stop at anything else (another packet type, QoS 2, v5 properties such as subscription
        identifiers, a topic that is not UTF-8, a packet not all here yet), which paho then reads as
        usual. Returns how many were taken. Call only between packets (paho holds no partial one)."""
        buf, pos, size = self._buf, self._pos, len(self._buf)
        taken = 0
        while taken < limit and pos < size:
            first = buf[pos]
            if first >> 4 != 3 or first & 0x04:
                break  # not a PUBLISH, or QoS 2 (or the invalid 3)
            p, length, shift = pos + 1, 0, 0
            while p < size and shift <= 21:
                byte = buf[p]
                p += 1
                length |= (byte & 0x7F) << shift
                if byte < 0x80:
                    break
                shift += 7
            else:
                break  # remaining length not all here (or malformed: paho says so)
            end = p + length
            if end > size or p + 2 > end:
                break
            topic_end = p + 2 + ((buf[p] << 8) | buf[p + 1])
            qos = (first >> 1) & 0x03
            body = topic_end + (2 if qos else 0)
            if body + (1 if v5 else 0) > end or (v5 and buf[body] != 0):
                break  # truncated, or v5 properties: paho parses those
            try:
                topic = buf[p + 2 : topic_end].decode()
            except UnicodeDecodeError:
                break
            mid = (buf[topic_end] << 8) | buf[topic_end + 1] if qos else 0
            sink(topic, buf[body + 1 if v5 else body : end], bool(first & 0x01), qos, mid)
            pos = end
            taken += 1
        if pos >= size:
            self._buf, self._pos = b"", 0
        else:
            self._pos = pos
        return taken

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sock, name)


class ChunkReadingClient(mqtt.Client):
    """paho's client over :class:`ReadBufferedSocket` (plain TCP only; TLS sockets buffer themselves),
    reading every buffered packet per network-loop turn instead of one."""

    #: set by the bridge: plain PUBLISH packets go here without paho's per-packet work
    fast_publish: PublishSink | None = None
    #: PUBLISH packets taken by the fast path (the rest went through paho)
    fast_taken = 0

    def _create_socket(self) -> Any:
        sock = super()._create_socket()
        if type(sock) is socket.socket:
            return ReadBufferedSocket(sock)
        return sock

    def puback_many(self, mids: list[int]) -> None:
        """PUBACK many QoS 1 messages as one queued write (paho's ``ack`` queues and sends each 4-byte
        PUBACK on its own: a sixth of the ingest CPU)."""
        if mids:
            blob = b"".join([_PUBACK_HEADER + mid.to_bytes(2, "big") for mid in mids])
            self._packet_queue(_PUBACK, blob, 0, 1)

    def loop_read(self, max_packets: int = 1) -> MQTTErrorCode:
        sock: Any = self._sock
        if not isinstance(sock, ReadBufferedSocket):
            return super().loop_read(max_packets)
        buffered: ReadBufferedSocket = sock  # (``sock`` is compared with paho's current socket below)
        rc = MQTTErrorCode.MQTT_ERR_SUCCESS
        turns = 0  # bounded, so PUBACKs and pings still go out under a flood
        while self._sock is sock and turns < READ_TURN_PACKETS:
            sink = self.fast_publish
            if sink is not None and self._in_packet["command"] == 0:
                if not buffered.fill():
                    break  # nothing more to read now
                taken = buffered.take_publishes(sink, READ_TURN_PACKETS - turns, self._protocol == mqtt.MQTTv5)
                if taken:
                    self.fast_taken += taken
                    turns += taken
                    with self._msgtime_mutex:
                        self._last_bytes_received = time.monotonic()  # paho's keepalive clock
                    continue
            rc = super().loop_read(max_packets)  # one packet the fast path left (or the socket's news)
            turns += 1
            if rc != MQTTErrorCode.MQTT_ERR_SUCCESS or not buffered.pending():
                break
        return rc
