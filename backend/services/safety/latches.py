"""The e-stop and the holds survive anything: stored, restored at start, put back on a broker that lost them.

A latch (the fleet e-stop, a robot's hold) is a retained message, and a broker keeps retained messages only
as long as its memory (Mosquitto saves them every 30 s; the demo's embedded broker never). So each state
the server adopts is also stored (``safety_latches``), restored before the broker link starts, and after
every (re)connection compared with what the broker holds:

- Two states of one latch are ordered by their ``(ts, id)``: the newer wins.
- A latch (engaged) the broker holds always stands against a release the server remembers, older or newer:
  a release the broker lost is pressed again, never replayed. A release the broker holds is taken only when
  it is newer than the server's state (``fleet-agent estop --release`` after the server's latch).
- The server puts back only a latch newer than what the broker holds (or onto a broker that holds nothing),
  and never a release.

What the broker holds is known once the server's :class:`ServerSync` marker comes back: the broker delivers
the retained messages of the subscriptions made at the connection first (Mosquitto and amqtt queue them in
order, before the marker published after them).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import uuid
from typing import Any, Protocol

from backend.comms.base import Publisher
from fleet_protocol import QOS_SYNC, ServerSync, Topics, dumps

log = logging.getLogger(__name__)

#: how long an answer to an e-stop or a hold waits for its state to be stored (the database may be away: the
#: latch is on the broker already, and an answer must come)
STORE_WAIT_S = 2.0

#: orders two states of one latch: its message's ``ts``, then its ``id`` ("" when it has none)
Stamp = tuple[float, str]


def replaces(ours: Stamp | None, ours_engaged: bool, theirs: Stamp, theirs_engaged: bool) -> bool:
    """Whether a state from the broker replaces the server's (see the module docstring): a newer one does,
    and a latch replaces any release."""
    if ours is None:
        return True
    return theirs > ours or (theirs_engaged and not ours_engaged)


def lost_by_broker(ours: Stamp | None, ours_engaged: bool, on_broker: Stamp | None) -> bool:
    """Whether the server's state is a latch the broker has lost: it holds nothing, or an older state."""
    return ours is not None and ours_engaged and (on_broker is None or on_broker < ours)


async def wait_stored(stored: concurrent.futures.Future[Any] | None, what: str) -> None:
    """Wait (a bounded while) for a latch's state to be committed, so that an answer means "stored" too. The
    broker has the state already: a failed or slow store is logged, never a failed e-stop or hold (the
    writer keeps trying)."""
    if stored is None:
        return
    try:
        await asyncio.wait_for(asyncio.shield(asyncio.wrap_future(stored)), STORE_WAIT_S)
    except TimeoutError:
        log.error("the %s is not stored yet after %.0f s (it is on the broker)", what, STORE_WAIT_S)
    except Exception:
        log.exception("the %s was not stored (it is on the broker)", what)


class Latches(Protocol):
    """A service whose latches are put back after each (re)connection (the e-stop, the holds)."""

    def forget_broker(self) -> None:
        """A new connection: nothing is known of what the broker holds yet."""

    def put_back(self) -> int:
        """The broker's retained messages have all come: republish what it lost; returns how many."""


class LatchSync:
    """Publishes a :class:`ServerSync` marker at each (re)connection and, when its own comes back, has each
    service put back the latches the broker lost."""

    def __init__(self, *, publisher: Publisher, topics: Topics, server_id: str, services: list[Latches]) -> None:
        self._publisher = publisher
        self._topic = topics.sync()
        self._server_id = server_id[:64]
        self._services = services
        self._nonce: str | None = None
        #: syncs completed, and latches put back on the broker (counted for /api/health)
        self.synced = 0
        self.latches_put_back = 0

    def on_connection_change(self, connected: bool) -> None:
        """Event loop. The subscriptions are already sent: the marker follows them on the same connection."""
        if not connected:
            self._nonce = None
            return
        for service in self._services:
            service.forget_broker()
        self._nonce = uuid.uuid4().hex
        marker = ServerSync(server_id=self._server_id, nonce=self._nonce)
        self._publisher.publish(self._topic, dumps(marker), qos=QOS_SYNC, retain=False)

    def on_marker(self, marker: ServerSync) -> None:
        """A marker came back: another replica's, an earlier connection's, or the one awaited."""
        if marker.server_id != self._server_id or marker.nonce != self._nonce:
            return
        self._nonce = None
        put_back = sum(service.put_back() for service in self._services)
        self.latches_put_back += put_back
        self.synced += 1
        if put_back:
            log.warning("the broker had lost %d latch(es) (e-stop, holds): published again", put_back)
