"""The server's heartbeat: "a server is supervising". Published by every replica several times a second.

Robots on the old framework cannot hear it, so it names the seed command topics this server may have
driven: a sentinel beside the broker (comms/legacy_sentinel.py) stops them when the heartbeat goes silent
(a partition or a frozen server; the broker's own keepalive check takes seconds). Autonomous motion on new
agents stops when it goes silent, too.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Protocol

from backend.comms.base import Publisher
from fleet_protocol import HEARTBEAT_PERIOD_S, QOS_HEARTBEAT, ServerHeartbeat, Topics, dumps

log = logging.getLogger(__name__)


class DrivenTopics(Protocol):
    """The seed command topics this server may have driven (the legacy relay keeps them; it imports this
    domain, so the heartbeat asks through this protocol)."""

    def all_topics(self) -> list[str]: ...


class HeartbeatPublisher:
    def __init__(
        self,
        *,
        publisher: Publisher,
        topics: Topics,
        server_id: str,
        legacy: DrivenTopics,
        period_s: float = HEARTBEAT_PERIOD_S,
    ) -> None:
        self._publisher = publisher
        self._topic = topics.heartbeat()
        self.server_id = server_id[:64]
        self._legacy = legacy
        self._period_s = period_s
        self.sent = 0

    def beat(self) -> None:
        if not self._publisher.connected:
            return
        msg = ServerHeartbeat(
            server_id=self.server_id, ts=time.time(), seq=self.sent, legacy_topics=self._legacy.all_topics()
        )
        self._publisher.publish(self._topic, dumps(msg), qos=QOS_HEARTBEAT)
        self.sent += 1

    async def run(self) -> None:
        while True:
            try:
                self.beat()
            except Exception:
                log.exception("heartbeat failed")
            await asyncio.sleep(self._period_s)
