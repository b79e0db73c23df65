"""Telemetry ordering across a broker outage (decided deliberately): the bookkeeping the MQTT link keeps.

* While the link is up and "ready", telemetry is handed straight to paho (QoS 1). paho keeps every QoS 1
  message it has not had a PUBACK for and resends it after a reconnect; those "held-over" messages are the
  oldest ones, tracked here by message id.
* While the link is down (or not yet ready), telemetry goes into our own bounded buffer (drop-oldest, drops
  counted by the transport and reported in the status as ``buffer_dropped``); paho never sees it.
* On reconnect the transport publishes the online status, then waits until every held-over message is
  acked (paho resends them right after CONNACK), then flushes the buffer in order, then marks the link
  ready again. So the broker receives telemetry in seq order without gaps (apart from counted drops). A
  held-over message that never gets acked (the broker lost it) releases the flush after a timeout.

Kept apart from :mod:`.mqtt` so the ordering rules read in one place, without paho's plumbing around them.
Used on the asyncio loop, except :meth:`TelemetryOutbox.acked`, which paho's thread calls.
"""

from __future__ import annotations

import collections
import time

#: a telemetry message as the transport publishes it: (topic, payload, retain)
Message = tuple[str, bytes, bool]

#: PUBACKs of untracked publishes are forgotten after this long (only microseconds-old entries matter)
_EARLY_ACK_TTL_S = 5.0


class TelemetryOutbox:
    """The offline buffer and the held-over message ids; the transport decides when to hand and to flush."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._buffer: collections.deque[Message] = collections.deque()
        self._pending: set[int] = set()  # telemetry mids handed to paho, not yet PUBACKed
        self._early: dict[int, float] = {}  # PUBACKs seen before we recorded the mid
        # Appended by the paho thread, drained on the loop (deque appends and pops are atomic).
        self._acked: collections.deque[int] = collections.deque()

    def hold(self, message: Message) -> bool:
        """Buffer a message while the link is not ready. True when the oldest one was dropped for it."""
        dropped = len(self._buffer) >= self.size
        if dropped:
            self._buffer.popleft()
        self._buffer.append(message)
        return dropped

    def take(self) -> list[Message]:
        """Everything buffered, oldest first; the buffer is empty afterwards."""
        messages = list(self._buffer)
        self._buffer.clear()
        return messages

    def handed(self, mid: int) -> None:
        """paho accepted a telemetry message: it is held over until its PUBACK (which may already be in)."""
        self._drain_acks()
        if self._early.pop(mid, None) is None:
            self._pending.add(mid)

    def acked(self, mid: int) -> None:
        """A PUBACK, on paho's thread with its message lock held: only record the id, never take locks."""
        self._acked.append(mid)

    def held_over(self) -> int:
        """Telemetry handed to paho that has no PUBACK yet (paho resends it after a reconnect)."""
        self._drain_acks()
        return len(self._pending)

    def forget_held_over(self) -> None:
        """The broker lost them: stop waiting, so the buffer can be flushed."""
        self._pending.clear()

    def _drain_acks(self) -> None:
        now = time.monotonic()
        while self._acked:
            mid = self._acked.popleft()
            if mid in self._pending:
                self._pending.discard(mid)
            else:
                self._early[mid] = now
        if len(self._early) > 64:  # acks of untracked publishes pile up here: prune the old ones
            self._early = {m: t for m, t in self._early.items() if now - t < _EARLY_ACK_TTL_S}
