"""Live hub: fans messages out to WebSocket clients without ever blocking ingest.

Each message is serialised once (orjson) and the same bytes are queued for every interested client.
Each client has a bounded queue: when it is full, the oldest telemetry of the same (robot, stream) is
dropped first (coalescing), else the oldest telemetry of the busiest stream; drops are counted. Control
messages (snapshot, robot, command, estop) are never coalesced. A per-client sender task sends one JSON
array frame with everything queued as soon as it can; only a client that is behind batches for a flush
interval between frames.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from collections import deque
from collections.abc import Awaitable, Callable
from typing import Any

import orjson

log = logging.getLogger(__name__)

Key = tuple[str, str]
_order = itertools.count()


class LiveClient:
    def __init__(
        self,
        send: Callable[[str], Awaitable[None]],
        queue_max: int,
        flush_interval_s: float,
        control_max: int = 10_000,
    ) -> None:
        self._send = send
        self._queue_max = queue_max
        self._control_max = control_max
        self._flush_interval = flush_interval_s
        self.robots: frozenset[str] | None = frozenset()  # None: all robots; empty: not subscribed yet
        self.streams: frozenset[str] | None = None
        #: per (robot, stream), what was queued since the last frame; a frame takes them all and starts
        #: afresh, so it visits only these, not every key ever seen (100 robots, ~2 messages per frame:
        #: walking all 100 was a tenth of the loop)
        self._telemetry: dict[Key, deque[tuple[int, bytes]]] = {}
        self._telemetry_count = 0
        self._control: deque[tuple[int, bytes]] = deque()
        self._wake = asyncio.Event()
        self.dropped = 0
        self.sent_frames = 0
        self.too_slow = False
        #: which robot/command/estop messages this client wants (None: all): a controller's socket skips
        #: the accepted/done of each of its own set-points
        self.control_filter: Callable[[dict[str, Any]], bool] | None = None

    def subscribe(self, robots: list[str], streams: list[str]) -> None:
        self.robots = None if "*" in robots else frozenset(robots)
        self.streams = None if "*" in streams else frozenset(streams)

    def wants_robot(self, robot_id: str | None) -> bool:
        if robot_id is None:
            return self.robots is None or bool(self.robots)
        return self.robots is None or robot_id in self.robots

    def wants_stream(self, stream: str) -> bool:
        return self.streams is None or stream in self.streams

    def offer_control(self, data: bytes) -> None:
        if len(self._control) >= self._control_max:
            self.too_slow = True  # the sender closes the connection; the client reconnects for a snapshot
        else:
            self._control.append((next(_order), data))
        self._wake.set()

    def offer_telemetry(self, key: Key, data: bytes) -> None:
        q = self._telemetry.get(key)
        if q is None:
            q = self._telemetry[key] = deque()
        if self._telemetry_count >= self._queue_max:
            victim = q if q else max(self._telemetry.values(), key=len)
            victim.popleft()
            self._telemetry_count -= 1
            self.dropped += 1
        q.append((next(_order), data))
        self._telemetry_count += 1
        self._wake.set()

    def _take_frame(self) -> str | None:
        items = list(self._control)
        self._control.clear()
        for q in self._telemetry.values():
            items.extend(q)
        self._telemetry.clear()
        self._telemetry_count = 0
        if not items:
            return None
        items.sort(key=lambda it: it[0])
        return (b"[" + b",".join(d for _, d in items) + b"]").decode()

    async def run(self) -> None:
        """Sender loop: an idle client gets each drain's messages at once (a fixed pause after every frame
        added about half the flush interval to every message's latency); a client whose last send had to
        wait (its socket buffer was full: a slow reader) pauses one flush interval so its next frame batches
        more. Frames still batch naturally: one MQTT drain queues many messages before the sender runs."""
        loop = asyncio.get_running_loop()
        while True:
            await self._wake.wait()
            self._wake.clear()
            if self.too_slow:
                raise ConnectionError("client too slow: control queue overflow")
            frame = self._take_frame()
            if frame is None:
                continue
            started = loop.time()
            await self._send(frame)
            self.sent_frames += 1
            if loop.time() - started >= self._flush_interval:
                await asyncio.sleep(self._flush_interval)  # backlogged: batch the next frame
            else:
                await asyncio.sleep(0)  # let the rest of this burst's drains queue before the next frame


class LiveHub:
    def __init__(self, queue_max: int = 2000, flush_interval_s: float = 0.03) -> None:
        self._queue_max = queue_max
        self._flush_interval = flush_interval_s
        self.clients: set[LiveClient] = set()
        self.messages = 0
        self._dropped_closed = 0

    def add(self, send: Callable[[str], Awaitable[None]]) -> LiveClient:
        client = LiveClient(send, self._queue_max, self._flush_interval)
        self.clients.add(client)
        return client

    def remove(self, client: LiveClient) -> None:
        if client in self.clients:
            self.clients.discard(client)
            self._dropped_closed += client.dropped

    def stats(self) -> dict[str, int]:
        return {
            "clients": len(self.clients),
            "messages": self.messages,
            "dropped": self._dropped_closed + sum(c.dropped for c in self.clients),
        }

    @staticmethod
    def encode(message: dict[str, Any]) -> bytes:
        return orjson.dumps(message)

    def publish_telemetry(self, robot_id: str, stream: str, ts: float, seq: int, data: dict[str, Any]) -> None:
        if not self.clients:
            return
        encoded: bytes | None = None
        key = (robot_id, stream)
        for c in self.clients:
            if c.wants_robot(robot_id) and c.wants_stream(stream):
                if encoded is None:
                    encoded = self.encode(
                        {
                            "type": "telemetry",
                            "robot_id": robot_id,
                            "stream": stream,
                            "ts": ts,
                            "seq": seq,
                            "data": data,
                        }
                    )
                c.offer_telemetry(key, encoded)
        self.messages += 1

    def publish_control(self, message: dict[str, Any], robot_id: str | None = None) -> None:
        """A robot/command/estop message; ``robot_id`` None means it goes to every subscribed client."""
        if not self.clients:
            return
        encoded: bytes | None = None
        for c in self.clients:
            if c.wants_robot(robot_id) and (c.control_filter is None or c.control_filter(message)):
                if encoded is None:
                    encoded = self.encode(message)
                c.offer_control(encoded)
        self.messages += 1
