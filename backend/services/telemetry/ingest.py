"""Telemetry ingest: registry bookkeeping, queue the row for the writer thread, fan out live.

Single server: every telemetry message comes through the dispatcher and is stored, counted and fanned
out here. Replicas (``FLEET_INGEST_SHARED_GROUP``): each message reaches exactly one replica through the
shared subscription and is only stored (:meth:`TelemetryIngest.store_batch`); every replica also gets
every message through its own live subscription, which updates the registry and its WebSocket clients
but is not stored again. Legacy robots always go the dispatcher way (their seq is assigned here).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import orjson

from backend.comms.base import InboundMessage
from backend.core.logging import RateLimitedLogger
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.store.writer import BatchWriter
from fleet_protocol import RETAINED_STREAMS, ProtocolError, TopicKind, Topics, decode_telemetry

log = logging.getLogger(__name__)


def telemetry_row(
    robot_id: str, stream: str, ts: float, seq: int, data: dict[str, Any], recv_ts: float | None = None
) -> dict[str, Any]:
    """The telemetry table row: payload as JSON, x/y/z/yaw as typed columns for position, and ``recv_ts``
    (the server's receive time) beside the robot's ``ts``."""
    row: dict[str, Any] = {
        "robot_id": robot_id,
        "stream": stream,
        "ts": ts,
        "recv_ts": recv_ts,
        "seq": seq,
        "x": None,
        "y": None,
        "z": None,
        "yaw": None,
        "payload": orjson.dumps(data).decode(),
    }
    if stream == "position":
        row["x"], row["y"], row["z"], row["yaw"] = (data.get("x"), data.get("y"), data.get("z"), data.get("yaw"))
    return row


class TelemetryIngest:
    def __init__(
        self,
        registry: Registry,
        writer: BatchWriter,
        hub: LiveHub,
        topics: Topics,
        *,
        buffered: bool = False,
        stored_via_shared: Callable[[], bool] | None = None,
        taps: list[Callable[[str, str, float, int, dict[str, Any]], None]] | None = None,
    ) -> None:
        self._registry = registry
        self._writer = writer
        self._hub = hub
        self._topics = topics
        self._rl = RateLimitedLogger(log)
        #: True while telemetry is stored through the shared subscription (replicas on an MQTT v5 broker)
        self.stored_via_shared: Callable[[], bool] = stored_via_shared or (lambda: False)
        #: collect rows and hand them to the writer once per MQTT drain (:meth:`drained`), not one by one
        self.buffered = buffered
        self._pending: list[dict[str, Any]] = []
        self.stored_shared = 0
        self.shared_rejects = 0
        #: further live consumers of every message received (the Foxglove server), called after the hub
        self.taps: list[Callable[[str, str, float, int, dict[str, Any]], None]] = list(taps or [])

    def ingest(
        self,
        robot_id: str,
        stream: str,
        ts: float,
        seq: int,
        data: dict[str, Any],
        received: float,
        legacy: bool = False,
    ) -> None:
        st = self._registry.ensure(robot_id, received)
        self._registry.record_telemetry(st, stream, seq, ts, data, received)
        if stream in RETAINED_STREAMS:
            st.retained[stream] = (ts, seq, data)
        if legacy or not self.stored_via_shared():
            self._store(telemetry_row(robot_id, stream, ts, seq, data, received))
        self._hub.publish_telemetry(robot_id, stream, ts, seq, data)
        for tap in self.taps:
            tap(robot_id, stream, ts, seq, data)

    def store_repaired(
        self, robot_id: str, stream: str, messages: list[tuple[float, int, dict[str, Any]]], received: float
    ) -> None:
        """Messages a gap repair brought back, as (ts, seq, data) with their original ts: stored only (the
        live view and the stream counters have moved on), acked to the broker after their commit. Their
        ``recv_ts`` is when the repair reply arrived: when the server really got them."""
        for ts, seq, data in messages:
            self._store(telemetry_row(robot_id, stream, ts, seq, data, received))

    def _store(self, row: dict[str, Any]) -> None:
        if not self.buffered:
            self._writer.submit_telemetry(row)
            return
        self._pending.append(row)
        if len(self._pending) >= 1000:
            self.flush()

    def flush(self) -> None:
        if self._pending:
            rows, self._pending = self._pending, []
            self._writer.submit_rows(rows)

    def drained(self, ack_tokens: list[Any]) -> None:
        """After each MQTT drain: queue its rows, then the broker acks of its messages behind them."""
        self.flush()
        self._writer.submit_ack(ack_tokens)

    def store_batch(self, batch: list[InboundMessage]) -> None:
        """Messages of the shared subscription: store only. A bad one is counted here and dropped (the
        live copy of the same message is what the dispatcher counts as a reject)."""
        for msg in batch:
            try:
                parsed = self._topics.parse(msg.topic)
                if parsed.kind is not TopicKind.TELEMETRY or parsed.robot_id is None or parsed.stream is None:
                    raise ProtocolError("unexpected_topic", msg.topic[:120])
                t = decode_telemetry(msg.payload, parsed.stream)
            except ProtocolError as exc:
                self.shared_rejects += 1
                self._rl.warning(exc.reason, "shared ingest: %s on %s dropped", exc.reason, msg.topic[:120])
                continue
            self._store(telemetry_row(parsed.robot_id, parsed.stream, t.ts, t.seq, t.data, msg.received))
            self.stored_shared += 1
