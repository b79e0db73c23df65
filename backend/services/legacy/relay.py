"""Seed command strings for robots on the old Mollusca framework, with the safety they lack themselves.

A robot on the seed's framework drives until it hears ``"stop"``: it has no deadman and no e-stop of its
own. So the server holds them for it:

- a drive is sent (QoS 0) only to the topics its target listens on, and ``"stop"`` follows when the drive's
  ``duration_s`` lapses unless a renewal came first (the deadman, counted per topic: every robot on the
  shared topic hears every drive sent there, so they form one unit);
- while the fleet e-stop is latched no drive string is ever published, and ``"stop"`` goes to every legacy
  command topic at once, again every ``beacon_period_s``, and to any legacy robot that appears meanwhile;
- the server's MQTT Last Will is ``"stop"`` on the shared topic (see the container) and a clean shutdown
  sends it itself (:meth:`stop_all`); a sentinel beside the broker covers a partition (comms/legacy_sentinel).
"""

from __future__ import annotations

import asyncio
import logging

from backend.comms.base import Publisher
from backend.services.fleet.registry import Registry, RobotState
from fleet_protocol import (
    LEGACY_COMMAND_TOPIC,
    LEGACY_STOP,
    QOS_LEGACY_DRIVE,
    QOS_LEGACY_STOP,
    legacy_command_topics,
    legacy_namespaced_command_topic,
)

log = logging.getLogger(__name__)

ESTOP_BEACON_PERIOD_S = 1.0


class LegacyDriveRefused(RuntimeError):
    """A drive string was about to go out while it must not (the last guard before the broker)."""


class LegacyCommandRelay:
    def __init__(
        self, *, publisher: Publisher, registry: Registry, beacon_period_s: float = ESTOP_BEACON_PERIOD_S
    ) -> None:
        self._publisher = publisher
        self._registry = registry
        self._beacon_period_s = beacon_period_s
        #: topic -> the pending deadman stop of the drive running there
        self._deadman: dict[str, asyncio.TimerHandle] = {}
        self._estop_engaged = False
        self._beacon: asyncio.TimerHandle | None = None
        #: every topic a drive was ever sent to by this process (the heartbeat names them for the sentinel)
        self.driven_topics: set[str] = {LEGACY_COMMAND_TOPIC}

    # -- addressing --------------------------------------------------------------------------------------
    def topics_for(self, st: RobotState) -> list[str]:
        return legacy_command_topics(st.id, st.legacy_listens_on)

    def all_topics(self) -> list[str]:
        """Every seed command topic: the shared one and each known legacy robot's own (a stop to a topic
        nobody listens on costs nothing; one a robot listens on that we left out could cost a wall)."""
        topics = {LEGACY_COMMAND_TOPIC}
        for st in self._registry.robots.values():
            if st.legacy:
                topics.add(legacy_namespaced_command_topic(st.id))
        return sorted(topics | self.driven_topics)

    # -- commands ----------------------------------------------------------------------------------------
    def drive(self, st: RobotState, command: str, duration_s: float) -> None:
        """Publish a seed drive string and arm its deadman. Refuses while the e-stop is latched."""
        if self._estop_engaged:
            raise LegacyDriveRefused("fleet e-stop engaged: no drive string goes out")
        loop = asyncio.get_running_loop()
        for topic in self.topics_for(st):
            self.driven_topics.add(topic)
            self._publisher.publish(topic, command, qos=QOS_LEGACY_DRIVE)
            pending = self._deadman.pop(topic, None)
            if pending is not None:
                pending.cancel()
            self._deadman[topic] = loop.call_later(duration_s, self._lapsed, topic)

    def stop(self, st: RobotState) -> None:
        """A shared-topic robot stops with its unit (its own topic too, in case it listens there); a robot
        on its own topic alone."""
        own = legacy_namespaced_command_topic(st.id)
        self._stop_topics([own] if st.legacy_listens_on == "own" else [LEGACY_COMMAND_TOPIC, own])

    def stop_all(self, why: str) -> None:
        topics = self.all_topics()
        log.info("stop to every legacy command topic (%s): %s", why, ", ".join(topics))
        self._stop_topics(topics)

    def _stop_topics(self, topics: list[str]) -> None:
        for topic in topics:
            pending = self._deadman.pop(topic, None)
            if pending is not None:
                pending.cancel()
            self._publisher.publish(topic, LEGACY_STOP, qos=QOS_LEGACY_STOP)

    def _lapsed(self, topic: str) -> None:
        """The drive on ``topic`` was not renewed within its duration: the server's deadman stops it."""
        self._deadman.pop(topic, None)
        self._publisher.publish(topic, LEGACY_STOP, qos=QOS_LEGACY_STOP)

    # -- e-stop and robots appearing ----------------------------------------------------------------------
    def set_estop(self, engaged: bool) -> None:
        """Latched: stop everything now and every beacon period until released."""
        was = self._estop_engaged
        self._estop_engaged = engaged
        if engaged:
            self.stop_all("fleet e-stop")
            if not was:
                self._schedule_beacon()
        elif self._beacon is not None:
            self._beacon.cancel()
            self._beacon = None

    def _schedule_beacon(self) -> None:
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # outside the server's loop (tools, tests of the service alone)
            return
        self._beacon = loop.call_later(self._beacon_period_s, self._beat)

    def _beat(self) -> None:
        self._beacon = None
        if not self._estop_engaged:
            return
        self._stop_topics(self.all_topics())
        self._schedule_beacon()

    def on_appeared(self, st: RobotState, held: bool) -> None:
        """A legacy robot came online: while the e-stop is latched, or it is held, it hears "stop" at once,
        on every topic it might listen on (a new robot's addressing is not known yet)."""
        if self._estop_engaged:
            self._stop_topics([LEGACY_COMMAND_TOPIC, legacy_namespaced_command_topic(st.id)])
        elif held:
            self.stop(st)

    def close(self) -> None:
        for pending in self._deadman.values():
            pending.cancel()
        self._deadman.clear()
        if self._beacon is not None:
            self._beacon.cancel()
            self._beacon = None
