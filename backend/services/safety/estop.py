"""Fleet e-stop: a RETAINED ``fleet/estop`` message latches it (also for robots that reboot) until released.

The state follows the topic itself (the server subscribes to it), so the retained message restores it
after a server restart and replicas agree. Robots ack with the e-stop's id on their ack topic.
"""

from __future__ import annotations

import logging
import time
import uuid

from backend.comms.base import Publisher
from backend.schemas import EStopEngaged, EStopPublic
from backend.services.fleet.registry import Registry
from backend.services.legacy.relay import LegacyCommandRelay
from backend.services.live.hub import LiveHub
from backend.store import repository as repo
from backend.store.writer import BatchWriter
from fleet_protocol import QOS_ESTOP, Ack, EStop, Topics, dumps

log = logging.getLogger(__name__)


class EStopService:
    def __init__(
        self,
        registry: Registry,
        publisher: Publisher,
        topics: Topics,
        writer: BatchWriter,
        hub: LiveHub,
        *,
        legacy: LegacyCommandRelay,
    ) -> None:
        self._legacy = legacy
        self._registry = registry
        self._publisher = publisher
        self._topics = topics
        self._writer = writer
        self._hub = hub
        self.state = EStopPublic(engaged=False, ts=None, id=None, reason="", source="", acks={})
        self._ids: set[str] = set()

    def _apply(self, msg: EStop) -> None:
        if msg.id is not None and msg.id == self.state.id and msg.engaged == self.state.engaged:
            return  # our own publish echoed back by the broker
        self.state = EStopPublic(
            engaged=msg.engaged, ts=msg.ts, id=msg.id, reason=msg.reason, source=msg.source, acks={}
        )
        # robots on the old framework have no e-stop of their own: "stop" to every one, now and each second
        self._legacy.set_estop(msg.engaged)
        if msg.id:
            self._ids.add(msg.id)
        self._writer.submit(
            repo.insert_event(
                time.time(),
                "estop" if msg.engaged else "estop_release",
                None,
                {"id": msg.id, "reason": msg.reason, "source": msg.source},
            )
        )
        self.push()

    def engage(self, reason: str, source: str) -> EStopEngaged:
        msg = EStop(ts=time.time(), id=str(uuid.uuid4()), engaged=True, reason=reason, source=source)
        self._publisher.publish(self._topics.estop(), dumps(msg), qos=QOS_ESTOP, retain=True)
        self._apply(msg)
        log.warning("E-STOP engaged (%s) by %s", reason or "no reason", source)
        robots = [r.id for r in self._registry.robots.values() if r.online]
        return EStopEngaged(id=msg.id or "", ts=msg.ts, engaged=True, robots=sorted(robots))

    def release(self, reason: str, source: str) -> EStopEngaged:
        msg = EStop(ts=time.time(), id=str(uuid.uuid4()), engaged=False, reason=reason, source=source)
        self._publisher.publish(self._topics.estop(), dumps(msg), qos=QOS_ESTOP, retain=True)
        self._apply(msg)
        log.warning("e-stop released by %s", source)
        robots = [r.id for r in self._registry.robots.values() if r.online]
        return EStopEngaged(id=msg.id or "", ts=msg.ts, engaged=False, robots=sorted(robots))

    @property
    def engaged(self) -> bool:
        return self.state.engaged

    def refusal(self) -> str:
        """Why a drive is refused while latched: the e-stop's reason and who engaged it."""
        who = self.state.source or "unknown"
        why = f": {self.state.reason}" if self.state.reason else ""
        return f"fleet e-stop engaged by {who}{why}; only stop passes until it is released"

    # -- from the broker ---------------------------------------------------------------------------------
    def on_estop(self, msg: EStop) -> None:
        self._apply(msg)

    def owns_ack(self, ack_id: str) -> bool:
        return ack_id in self._ids

    def on_ack(self, robot_id: str, ack: Ack, received: float) -> None:
        if ack.id == self.state.id:
            self.state.acks[robot_id] = ack.status
            self.push()
        self._writer.submit(
            repo.insert_event(
                received, "estop_ack", robot_id, {"id": ack.id, "status": ack.status, "reason": ack.reason}
            )
        )

    def push(self) -> None:
        self._hub.publish_control({"type": "estop", "estop": self.state.model_dump(mode="json")})
