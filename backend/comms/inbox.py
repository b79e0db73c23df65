"""The bridge's bounded inbox: messages read from the broker wait here for one drain per loop turn.

A drain hands up to :data:`DRAIN_BATCH` messages to the dispatcher (and a replica's store-only messages to
``on_store``), then the QoS 1 ack tokens of that drain to ``on_ack_marker`` (the writer acks them after
the commit of what they caused), or straight to ``ack`` when no marker is set.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from backend.comms.base import STORE_ID, AckToken, InboundMessage

log = logging.getLogger(__name__)

#: Messages handed to the dispatcher per drain; more are left for the next drain so the loop stays responsive.
DRAIN_BATCH = 2000


class Inbox:
    def __init__(
        self,
        queue_max: int,
        on_messages: Callable[[list[InboundMessage]], None],
        on_store: Callable[[list[InboundMessage]], None] | None,
        on_ack_marker: Callable[[list[AckToken]], Any] | None,
        ack: Callable[[list[AckToken]], None],
    ) -> None:
        self._queue: deque[InboundMessage] = deque()
        self._queue_max = queue_max
        self._on_messages = on_messages
        self._on_store = on_store
        self._on_ack_marker = on_ack_marker
        self._ack = ack
        self._drain_scheduled = False
        self.loop: asyncio.AbstractEventLoop | None = None
        self.received = 0
        self.dropped = 0
        self.errors = 0

    def __len__(self) -> int:
        return len(self._queue)

    def accept(
        self, topic: str, payload: bytes, retain: bool, qos: int, mid: int, gen: int, sub_ids: tuple[int, ...]
    ) -> None:
        self.received += 1
        if qos == 0 and len(self._queue) >= self._queue_max:
            # QoS 1 is never dropped here: its count is bounded by the receive maximum (unacked)
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 1000 == 0:
                log.warning("MQTT inbox full (%d): %d messages dropped", self._queue_max, self.dropped)
            return
        self._queue.append(InboundMessage(topic, payload, retain, time.time(), qos, mid, gen, sub_ids))
        if not self._drain_scheduled and self.loop is not None:
            self._drain_scheduled = True
            self.loop.call_soon(self._drain)  # once per read: the drain takes the whole batch

    def _drain(self) -> None:
        self._drain_scheduled = False
        batch: list[InboundMessage] = []
        queue = self._queue
        while queue and len(batch) < DRAIN_BATCH:
            batch.append(queue.popleft())
        if queue and self.loop is not None:
            self._drain_scheduled = True
            self.loop.call_soon(self._drain)
        if not batch:
            return
        dispatch: list[InboundMessage] = []
        store: list[InboundMessage] = []
        tokens: list[AckToken] = []
        for m in batch:
            if m.qos:
                tokens.append((m.gen, m.mid))
            if STORE_ID in m.sub_ids and self._on_store is not None:
                store.append(m)
                if len(m.sub_ids) == 1:
                    continue
            dispatch.append(m)
        try:
            if dispatch:
                self._on_messages(dispatch)
            if store and self._on_store is not None:
                self._on_store(store)
        except Exception:
            self.errors += 1
            log.exception("error dispatching %d MQTT messages", len(batch))
        if self._on_ack_marker is not None:
            self._on_ack_marker(tokens)  # acked after the writes these messages caused are committed
        elif tokens:
            self._ack(tokens)
