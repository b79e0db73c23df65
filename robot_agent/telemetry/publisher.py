"""Telemetry envelopes: the one place the agent stamps ``ts`` and the per-stream ``seq``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fleet_protocol import Topics, encode_telemetry, now

TelemetrySink = Callable[[str, bytes, bool], None]
#: sees every message as published: (stream, seq, payload); the replay ring keeps them for gap repair
PublishedHook = Callable[[str, int, bytes], None]


class TelemetryPublisher:
    """``emit(stream, data)`` -> ``{"ts", "seq", "data"}`` on ``fleet/{id}/telemetry/{stream}``.

    ``seq`` starts at 0 per stream and increases by exactly 1 per message, so a consumer can detect loss;
    ``boot`` (when given) names this run of the agent, because ``seq`` starts again at 0 after a restart.
    Used only from the asyncio loop (no locking needed).
    """

    def __init__(
        self,
        topics: Topics,
        robot_id: str,
        sink: TelemetrySink,
        boot: str | None = None,
        on_published: PublishedHook | None = None,
    ) -> None:
        self._topics = topics
        self._robot_id = robot_id
        self._sink = sink
        self.boot = boot
        self._on_published = on_published
        self._seq: dict[str, int] = {}
        self._topic_cache: dict[str, str] = {}
        self.counts: dict[str, int] = {}

    def emit(self, stream: str, data: dict[str, Any], retain: bool = False) -> int:
        topic = self._topic_cache.get(stream)
        if topic is None:
            topic = self._topic_cache[stream] = self._topics.telemetry(self._robot_id, stream)
        seq = self._seq.get(stream, 0)
        self._seq[stream] = seq + 1
        self.counts[stream] = self.counts.get(stream, 0) + 1
        payload = encode_telemetry(seq, data, ts=now(), boot=self.boot)
        if self._on_published is not None:
            self._on_published(stream, seq, payload)
        self._sink(topic, payload, retain)
        return seq
