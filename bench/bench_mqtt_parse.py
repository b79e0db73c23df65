"""The server's cost per incoming MQTT message: paho's parser against the bridge's PUBLISH fast path.

The same stream of MQTT v5 QoS 1 position messages (as robots publish them) is read by the bridge's own
client class (``ChunkReadingClient`` over ``ReadBufferedSocket``, what the server runs) twice: with the
fast path on (plain PUBLISH packets taken straight from the read buffer) and off (paho parses every
packet and calls ``on_message``). No network: an in-memory socket hands out the bytes, so the figure is
the parsing alone, per message, on one core.

    .venv/bin/python bench/bench_mqtt_parse.py [--messages 50000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import orjson

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from paho.mqtt.enums import CallbackAPIVersion, MQTTProtocolVersion

from backend.comms.fast_path import ChunkReadingClient, ReadBufferedSocket
from bench.common import report
from bench.rawmqtt import publish_packet


class _MemorySocket:
    """What the broker sent, handed out as a socket would (64 KiB reads, then "would block")."""

    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 0

    def recv(self, n: int) -> bytes:
        if self.pos >= len(self.data):
            raise BlockingIOError
        out = self.data[self.pos : self.pos + n]
        self.pos += len(out)
        return out

    def send(self, data: bytes) -> int:
        return len(data)

    def close(self) -> None:
        pass


def stream(messages: int) -> bytes:
    packets = []
    for i in range(messages):
        payload = orjson.dumps({"ts": 1.7e9 + i / 1000, "seq": i, "data": {"x": 0.3, "y": 0.6, "z": 0.0, "yaw": 0.1}})
        packets.append(
            publish_packet(
                f"fleet/robot-{i % 100:03d}/telemetry/position", payload, qos=1, packet_id=i % 65535 + 1, properties=b""
            )
        )
    return b"".join(packets)


def read_all(data: bytes, messages: int, fast: bool) -> float:
    """Seconds to read every message of ``data`` through the bridge's client (fast path on or off)."""
    got: list[Any] = []
    client = ChunkReadingClient(
        CallbackAPIVersion.VERSION2, client_id="bench-parse", protocol=MQTTProtocolVersion.MQTTv5
    )
    client.manual_ack_set(True)
    client.on_message = lambda c, u, msg: got.append((msg.topic, bytes(msg.payload), msg.retain, msg.qos, msg.mid))
    if fast:
        client.fast_publish = lambda *m: got.append(m)
    client._sock = ReadBufferedSocket(_MemorySocket(data))  # type: ignore[arg-type]
    t = time.perf_counter()
    while len(got) < messages:
        client.loop_read()
    elapsed = time.perf_counter() - t
    client._sock = None
    if fast and client.fast_taken < messages * 0.99:
        raise RuntimeError(f"the fast path took only {client.fast_taken} of {messages}")
    return elapsed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--messages", type=int, default=50_000)
    p.add_argument("--repeat", type=int, default=5, help="best of this many reads of the stream")
    args = p.parse_args()
    data = stream(args.messages)
    paho_s = min(read_all(data, args.messages, fast=False) for _ in range(args.repeat))
    fast_s = min(read_all(data, args.messages, fast=True) for _ in range(args.repeat))
    r = {
        "messages": args.messages,
        "bytes_per_message": len(data) / args.messages,
        "paho_us_per_msg": paho_s / args.messages * 1e6,
        "fast_us_per_msg": fast_s / args.messages * 1e6,
        "paho_msg_s": args.messages / paho_s,
        "fast_msg_s": args.messages / fast_s,
    }
    report(
        "mqtt-parse",
        [
            ("paho parser (us per message)", f"{r['paho_us_per_msg']:.1f}", "-", "-"),
            ("bridge fast path (us per message)", f"{r['fast_us_per_msg']:.1f}", "-", "-"),
            ("paho / fast path", f"{paho_s / fast_s:.0f}x", "-", "-"),
            ("fast path, one core (msg/s)", f"{r['fast_msg_s']:.0f}", "-", "-"),
        ],
        r,
    )


if __name__ == "__main__":
    main()
