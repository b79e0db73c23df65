"""What the agent's MQTT link listens to, and who hears each message: the topics to subscribe at every
connect and the handler for each message paho delivers. Kept apart from :mod:`.mqtt` (which owns paho and
the outgoing side) so the robot's inputs read in one table; no paho here."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from fleet_protocol import QOS_COMMAND, QOS_ESTOP, QOS_PING, QOS_REPAIR, QOS_TIME, Topics

Handler = Callable[[bytes], None]
#: a handler and its arguments, to be called on the asyncio loop
Delivery = tuple[Callable[..., Any], tuple[Any, ...]]


class Inbound:
    """The robot's subscriptions and their handlers. :meth:`route` runs on paho's thread: no I/O, no locks."""

    def __init__(
        self,
        topics: Topics,
        robot_id: str,
        *,
        on_command: Handler,
        on_estop: Handler,
        on_ping: Handler | None = None,
        on_time: Callable[[bytes, float], None] | None = None,
        on_repair: Handler | None = None,
        subscriptions: dict[str, tuple[int, Handler]] | None = None,
    ) -> None:
        self._cmd_topic = topics.cmd(robot_id)
        self._estop_topic = topics.estop()
        self._ping_topic = topics.ping(robot_id)
        self._time_resp_topic = topics.time_resp(robot_id)
        self._repair_request_topic = topics.repair_request(robot_id)
        self._on_command = on_command
        self._on_estop = on_estop
        self._on_ping = on_ping
        self._on_time = on_time
        self._on_repair = on_repair
        #: Further topics to hear (the server's heartbeat, the site): topic -> (QoS, handler on the loop).
        self._subscriptions = dict(subscriptions or {})

    def subscriptions(self) -> list[tuple[str, int]]:
        """(topic, QoS) to subscribe at each connect (the session is clean: the broker forgot them)."""
        subscriptions = [
            (self._cmd_topic, QOS_COMMAND),
            (self._estop_topic, QOS_ESTOP),
            (self._ping_topic, QOS_PING),
            (self._time_resp_topic, QOS_TIME),
            *((topic, qos) for topic, (qos, _) in self._subscriptions.items()),
        ]
        if self._on_repair is not None:
            subscriptions.append((self._repair_request_topic, QOS_REPAIR))
        return subscriptions

    def route(self, topic: str, payload: bytes) -> Delivery | None:
        """The handler for a message and its arguments, or None when nobody listens to ``topic``."""
        if topic == self._cmd_topic:
            return self._on_command, (payload,)
        if topic == self._estop_topic:
            return self._on_estop, (payload,)
        if topic == self._ping_topic and self._on_ping is not None:
            return self._on_ping, (payload,)
        if topic == self._time_resp_topic and self._on_time is not None:
            return self._on_time, (payload, time.monotonic())  # t3: read here, not after the loop's queue
        if topic == self._repair_request_topic and self._on_repair is not None:
            return self._on_repair, (payload,)
        if topic in self._subscriptions:
            return self._subscriptions[topic][1], (payload,)
        return None
