"""Forgetting a robot that is gone: out of the registry and the database, its retained messages cleared on
the broker (else its retained status, or a retained stream such as ``lighthouse_geometry``, brings it back at
the next subscribe), its telemetry kept or deleted as asked. Audited: an ``robot_forgotten`` event naming who
did it, and a WARNING in the log.

This is the server's side. ``fleet-server robots remove`` is the broker's side (the robot's MQTT
credentials): a robot that must never come back needs both."""

from __future__ import annotations

import asyncio
import logging
import time

from backend.comms.base import Publisher
from backend.core.errors import ServiceError
from backend.schemas import RobotForgotten, TelemetryChoice
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.store import repository as repo
from backend.store.writer import BatchWriter
from fleet_protocol import QOS_CONFIG, QOS_STATUS, RETAINED_STREAMS, Topics

log = logging.getLogger(__name__)


class RobotForgetter:
    def __init__(
        self, *, registry: Registry, publisher: Publisher, topics: Topics, writer: BatchWriter, hub: LiveHub
    ) -> None:
        self._registry = registry
        self._publisher = publisher
        self._topics = topics
        self._writer = writer
        self._hub = hub
        #: retained telemetry topics this server just cleared: the broker sends each clear (an empty
        #: message) to us too, and it is not a malformed message to count
        self._clearing: set[str] = set()

    async def forget(self, robot_id: str, telemetry: TelemetryChoice, by: str) -> RobotForgotten:
        st = self._registry.get(robot_id)
        if st is None:
            raise ServiceError(404, f"unknown robot {robot_id!r}", "unknown_robot")
        if st.online:
            raise ServiceError(
                409, f"robot {robot_id!r} is online: stop its agent first (it would come back at once)", "robot_online"
            )
        if not self._publisher.connected:
            raise ServiceError(
                503, "the server is not connected to the MQTT broker (its retained status stays)", "broker_unavailable"
            )
        self._registry.forget(robot_id)
        self._publisher.publish(self._topics.status(robot_id), b"", qos=QOS_STATUS, retain=True)
        self._publisher.publish(self._topics.config(robot_id), b"", qos=QOS_CONFIG, retain=True)
        for stream in sorted(RETAINED_STREAMS):
            topic = self._topics.telemetry(robot_id, stream)
            self._clearing.add(topic)
            self._publisher.publish(topic, b"", qos=1, retain=True)
        future = self._writer.submit(repo.delete_robot(robot_id, telemetry == "delete"), want_result=True)
        assert future is not None
        deleted = int(await asyncio.wrap_future(future))
        detail = {"by": by, "telemetry": telemetry, "rows_deleted": deleted}
        self._writer.submit(repo.insert_event(time.time(), "robot_forgotten", robot_id, detail))
        log.warning(
            "robot %s forgotten by %s (telemetry %s, %d rows deleted)",
            robot_id,
            by,
            telemetry,
            deleted,
            extra={"robot_id": robot_id, "client": by},
        )
        self._hub.publish_control({"type": "robot_forgotten", "robot_id": robot_id}, robot_id)
        return RobotForgotten(robot_id=robot_id, telemetry=telemetry, rows_deleted=deleted)

    def is_own_clear(self, topic: str, payload: bytes) -> bool:
        """An empty message on a retained topic this server cleared (the clear coming back to us)."""
        if payload or topic not in self._clearing:
            return False
        self._clearing.discard(topic)
        return True
