"""UDP listeners on the seed's ports: 5005 IMU, 5006 Lighthouse position, 5007 AprilTag JSON.

A port is opened only when a plugin subscribes to its kind (``position``/``imu`` with ``source =
"legacy"``, or the ``apriltag_legacy`` sensor), so several simulated agents on one machine never fight over
them. Every datagram is parsed into the stream's schema; bad datagrams are counted (rate-limited
warning) and dropped, never raised. Parsed samples go to bounded per-subscriber queues (drop-oldest).

Accepted formats:
- IMU (5005): ``"ax,ay,az,gx,gy,gz"`` (the seed's sender; spaces also work), a JSON list of 6 numbers, or
  ``{"accel": [3], "gyro": [3]}``  -> ``{"accel": [3], "gyro": [3]}``
- position (5006): see :func:`fleet_protocol.parse_position_text` -> ``{"x", "y", "z"[, "yaw"]}``
- AprilTag (5007): any JSON value (the seed module's pose dump) -> ``{"raw": <value>}`` on the
  ``apriltag_legacy`` stream (kept apart from the ``apriltag`` stream, whose schema the new detector uses).
"""

from __future__ import annotations

import asyncio
import logging
import math
import re
from collections.abc import Callable
from typing import Any

import orjson

from fleet_protocol import ImuData, ProtocolError, parse_position_text
from robot_agent.config import LegacyUdpConfig
from robot_agent.util import RejectCounter

log = logging.getLogger(__name__)

MAX_DATAGRAM = 16 * 1024
_SPLIT = re.compile(r"[\s,;]+")

KINDS = ("imu", "position", "apriltag")


def parse_imu(payload: bytes) -> dict[str, Any]:
    text = _text(payload, "bad_imu")
    value: Any
    if text[:1] in "[{":
        try:
            value = orjson.loads(text)
        except orjson.JSONDecodeError:
            raise ProtocolError("bad_imu", repr(text[:80])) from None
    else:
        value = [p for p in _SPLIT.split(text) if p]
    try:
        if isinstance(value, dict):
            return ImuData.model_validate(value).model_dump()
        if isinstance(value, list) and len(value) == 6 and not any(isinstance(v, bool) for v in value):
            nums = [float(v) for v in value]
            if not all(math.isfinite(v) for v in nums):
                raise ValueError("non-finite value")
            return {"accel": nums[:3], "gyro": nums[3:]}
    except (ValueError, TypeError) as exc:
        raise ProtocolError("bad_imu", str(exc)[:200]) from None
    raise ProtocolError("bad_imu", f"expected ax,ay,az,gx,gy,gz: {text[:80]!r}")


def parse_position(payload: bytes) -> dict[str, Any]:
    pos = parse_position_text(_text(payload, "bad_position"))
    return pos.model_dump(exclude_none=True)


def parse_apriltag(payload: bytes) -> dict[str, Any]:
    text = _text(payload, "bad_apriltag")
    try:
        return {"raw": orjson.loads(text)}
    except orjson.JSONDecodeError:
        raise ProtocolError("bad_apriltag", repr(text[:80])) from None


def _text(payload: bytes, reason: str) -> str:
    if len(payload) > MAX_DATAGRAM:
        raise ProtocolError(reason, f"datagram too large ({len(payload)} bytes)")
    try:
        text = payload.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise ProtocolError(reason, "not UTF-8") from None
    if not text:
        raise ProtocolError(reason, "empty datagram")
    return text


PARSERS: dict[str, Callable[[bytes], dict[str, Any]]] = {
    "imu": parse_imu,
    "position": parse_position,
    "apriltag": parse_apriltag,
}


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, hub: LegacyUdpHub, kind: str) -> None:
        self.hub = hub
        self.kind = kind

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.hub.feed(self.kind, data)

    def error_received(self, exc: Exception) -> None:
        log.warning("legacy UDP %s socket error: %s", self.kind, exc)


class LegacyUdpHub:
    """Owns the legacy UDP sockets and hands parsed samples to subscribed plugins."""

    QUEUE_SIZE = 100

    def __init__(self, config: LegacyUdpConfig) -> None:
        self.config = config
        self.rejects = RejectCounter(log)
        self.received: dict[str, int] = dict.fromkeys(KINDS, 0)
        self.dropped: dict[str, int] = dict.fromkeys(KINDS, 0)
        self._queues: dict[str, list[asyncio.Queue[dict[str, Any]]]] = {k: [] for k in KINDS}
        self._transports: dict[str, asyncio.DatagramTransport] = {}
        self._lock = asyncio.Lock()

    def port(self, kind: str) -> int:
        return int(getattr(self.config, f"{kind}_port"))

    def bound_port(self, kind: str) -> int | None:
        t = self._transports.get(kind)
        return None if t is None else int(t.get_extra_info("sockname")[1])

    async def subscribe(self, kind: str) -> asyncio.Queue[dict[str, Any]]:
        """A queue of parsed samples of ``kind``; opens the port on first use (raises OSError if taken)."""
        if kind not in PARSERS:
            raise ValueError(f"unknown legacy input {kind!r}")
        async with self._lock:
            if kind not in self._transports:
                loop = asyncio.get_running_loop()
                transport, _ = await loop.create_datagram_endpoint(
                    lambda: _Protocol(self, kind), local_addr=(self.config.bind, self.port(kind))
                )
                self._transports[kind] = transport
                log.info("legacy %s input listening on udp %s:%d", kind, self.config.bind, self.bound_port(kind))
        q: asyncio.Queue[dict[str, Any]] = asyncio.Queue(self.QUEUE_SIZE)
        self._queues[kind].append(q)
        return q

    def unsubscribe(self, kind: str, queue: asyncio.Queue[dict[str, Any]]) -> None:
        qs = self._queues.get(kind, [])
        if queue in qs:
            qs.remove(queue)
        if not qs and kind in self._transports:
            self._transports.pop(kind).close()

    def feed(self, kind: str, payload: bytes) -> None:
        """Parse one datagram and queue it for every subscriber; bad input is counted, never raised."""
        try:
            sample = PARSERS[kind](payload)
        except ProtocolError as exc:
            self.rejects.reject(exc.reason, exc.detail)
            return
        except Exception as exc:  # parser bug: count, keep listening
            self.rejects.reject(f"bad_{kind}", repr(exc))
            return
        self.received[kind] += 1
        for q in self._queues[kind]:
            if q.full():
                q.get_nowait()
                self.dropped[kind] += 1
            q.put_nowait(sample)

    def close(self) -> None:
        for t in self._transports.values():
            t.close()
        self._transports.clear()


def get_hub(shared: dict[str, Any]) -> LegacyUdpHub:
    hub = shared.get("legacy_udp")
    if not isinstance(hub, LegacyUdpHub):
        raise RuntimeError("legacy UDP inputs are not available in this agent")
    return hub
