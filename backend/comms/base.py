"""What the services know of the broker link, without paho: the inbound message, a subscription and the
:class:`Communicator` interface the MQTT bridge implements (``backend/comms/mqtt_bridge.py``).

Importing this module never loads paho, so the domain code (services, store, api) stays free of it.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any, Protocol

#: an ack token: (connection generation, packet id)
AckToken = tuple[int, int]

#: subscription role -> MQTT v5 subscription identifier
ROLE_IDS: dict[str, int] = {"control": 1, "telemetry": 2, "store": 3, "live": 4}
STORE_ID = ROLE_IDS["store"]


@dataclass(slots=True)
class InboundMessage:
    topic: str
    payload: bytes
    retain: bool
    received: float  # server wall clock, epoch seconds
    qos: int = 0
    mid: int = 0
    gen: int = 0
    #: subscription identifiers the broker sent (MQTT v5), empty otherwise
    sub_ids: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True)
class Subscription:
    topic: str
    qos: int
    role: str = "control"  # control | telemetry | store | live


class Publisher(Protocol):
    """What a service needs to send: the link's state and ``publish`` (services never see paho)."""

    @property
    def connected(self) -> bool: ...

    def publish(self, topic: str, payload: bytes | str, qos: int = 1, retain: bool = False) -> bool: ...


class Communicator(Protocol):
    """The server's link to the broker, as the services and the app use it."""

    #: True while the link speaks MQTT v5 (shared subscriptions and subscription identifiers work)
    v5: bool

    @property
    def connected(self) -> bool: ...

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Connect in the background on ``loop`` (and keep reconnecting)."""

    async def stop(self) -> None:
        """Disconnect (the broker keeps the session) and close the link."""

    def publish(self, topic: str, payload: bytes | str, qos: int = 1, retain: bool = False) -> bool:
        """Send (or queue, for QoS > 0 while disconnected); False when refused."""
        ...

    def ack(self, tokens: list[AckToken]) -> None:
        """Acknowledge committed QoS 1 messages (thread-safe)."""

    def stats(self) -> dict[str, Any]:
        """Counters for /api/stats and /metrics."""
        ...
