"""Answers the robots' clock-sync requests (fleet_protocol.clock) with the server's receive and send times.

Robots end a drive at the sender's ``ts + duration_s``, read on their own clock corrected by the offset
they measure here, so a delayed renewal never outlives its sender.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from backend.comms.base import Publisher
from fleet_protocol import QOS_TIME, Topics, dumps
from fleet_protocol.clock import TimeResponse, decode_time_request


class ClockService:
    def __init__(self, *, publisher: Publisher, topics: Topics, clock: Callable[[], float] = time.time) -> None:
        self._publisher = publisher
        self._topics = topics
        self._clock = clock
        self.answered = 0

    def on_request(self, robot_id: str, payload: bytes, received: float) -> None:
        """``received``: when the bridge read the request (t1). Raises ProtocolError for a bad payload."""
        req = decode_time_request(payload)
        resp = TimeResponse(t0=req.t0, t1=received, t2=self._clock())
        if self._publisher.publish(self._topics.time_resp(robot_id), dumps(resp), qos=QOS_TIME):
            self.answered += 1
