"""Withheld broker acks, and the reconnect that brings their messages back.

The writer withholds the PUBACK of a QoS 1 message whose rows or writes it had to give up (store/writer.py):
the broker still holds the message. But it sends an unacknowledged message again only on a new connection
of the session, and until then each one holds a slot of the in-flight window (the receive maximum; with
MQTT 3.1.1 the broker's ``max_inflight_messages``): withhold a window's worth and the broker sends nothing
more, live data included. So the bridge reconnects on purpose (a clean DISCONNECT, the session kept, no
Last Will) once acks were withheld on this connection and the writer has caught up (``ready``): the broker
delivers the withheld messages again, they are stored once (the unique key) and acked, and the window is
whole. Not sooner: while the database is away, what comes back would only be given up again. At most once
per :data:`REDELIVER_MIN_INTERVAL_S`, so a writer that keeps falling behind does not make the link flap.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

from backend.comms.base import AckToken

log = logging.getLogger(__name__)

#: the shortest time between two reconnects made to get withheld messages delivered again
REDELIVER_MIN_INTERVAL_S = 10.0


class Redelivery:
    """The bridge's bookkeeping of withheld acks (event loop only)."""

    def __init__(self, ready: Callable[[], bool] | None = None) -> None:
        #: True when what the broker delivers again can be stored (the writer has caught up)
        self._ready = ready or (lambda: True)
        #: acks withheld on the current connection: broker slots held until the next connection
        self.withheld_now = 0
        self.withheld = 0
        #: reconnects made for a redelivery
        self.reconnects = 0
        self._last = -math.inf
        #: the connection is being closed for a redelivery: reconnect at once
        self._reconnecting = False

    def withhold(self, tokens: list[AckToken], gen: int) -> None:
        """Tokens of an earlier connection hold no slot: the broker has sent those again already."""
        self.withheld += len(tokens)
        self.withheld_now += sum(1 for token_gen, _ in tokens if token_gen == gen)

    def connected(self) -> None:
        """A new connection: the broker delivers every unacknowledged message again on it."""
        self.withheld_now = 0

    def due(self, now: float) -> bool:
        if self.withheld_now <= 0 or now - self._last < REDELIVER_MIN_INTERVAL_S or not self._ready():
            return False
        log.warning(
            "%d broker acks withheld (their messages were not stored): reconnecting so that the broker "
            "delivers them again",
            self.withheld_now,
        )
        self._last = now
        self.reconnects += 1
        self._reconnecting = True
        return True

    def take_reconnect(self) -> bool:
        """True once after :meth:`due` closed the connection: reconnect without the usual delay."""
        now, self._reconnecting = self._reconnecting, False
        return now
