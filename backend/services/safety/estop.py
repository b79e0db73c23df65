"""Fleet e-stop: a RETAINED ``fleet/estop`` message latches it (also for robots that reboot) until released.

The state follows the topic (the server subscribes to it: replicas agree, and ``fleet-agent estop`` needs no
server), and each state is also stored and restored at start: a broker that lost its retained message gets
the latch back at the next connection (latches.py has the rules). Robots ack with the e-stop's id on their
ack topic. Every state is audited, whoever set it (estop_audit.py).
"""

from __future__ import annotations

import concurrent.futures
import logging
import time
from typing import Any

from backend.comms.base import Publisher
from backend.schemas import EStopEngaged, EStopPublic
from backend.services.access.audit import Actor, AuditService
from backend.services.fleet.registry import Registry
from backend.services.legacy.relay import LegacyCommandRelay
from backend.services.live.hub import LiveHub
from backend.services.safety import estop_audit
from backend.services.safety.latches import Stamp, lost_by_broker, replaces, wait_stored
from backend.store import latches as latch_store
from backend.store import repository as repo
from backend.store.latches import AfterStore
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
        audit: AuditService,
        signing_key: bytes,
    ) -> None:
        self._legacy = legacy
        self._audit = audit
        #: signs the ids of the e-stops this server publishes (FLEET_SECRET_KEY: every replica's)
        self._key = signing_key
        self._registry = registry
        self._publisher = publisher
        self._topics = topics
        self._writer = writer
        self._hub = hub
        self.state = EStopPublic(engaged=False, ts=None, id=None, reason="", source="", acks={})
        self._ids: set[str] = set()
        #: the newest message seen on the topic since the broker link (re)connected: what the broker holds
        self._on_broker: EStop | None = None
        #: the store of the newest state (the e-stop's routes wait for it)
        self._stored: concurrent.futures.Future[Any] | None = None

    def restore(self, row: dict[str, Any]) -> None:
        """At start, before the broker link: the stored state (the broker may have lost it since)."""
        self.state = EStopPublic(
            engaged=bool(row["engaged"]),
            ts=row["ts"],
            id=row["latch_id"],
            reason=row["reason"],
            source=row["source"],
            acks={},
        )
        self._legacy.set_estop(self.state.engaged)
        if self.state.id:
            self._ids.add(self.state.id)
        if self.state.engaged:
            log.warning("E-STOP latched (restored: %s by %s)", self.state.reason or "no reason", self.state.source)

    def _stamp(self) -> Stamp | None:
        return None if self.state.ts is None else (self.state.ts, self.state.id or "")

    def _apply(self, msg: EStop, actor: Actor | None = None, client_source: str = "") -> None:
        """Adopt, store and audit a state: ``actor`` pressed it through the API (``client_source``: the client
        they named), else it came through the broker."""
        if msg.id is not None and msg.id == self.state.id and msg.engaged == self.state.engaged:
            return  # our own publish echoed back by the broker
        self.state = EStopPublic(
            engaged=msg.engaged, ts=msg.ts, id=msg.id, reason=msg.reason, source=msg.source, acks={}
        )
        # robots on the old framework have no e-stop of their own: "stop" to every one, now and each second
        self._legacy.set_estop(msg.engaged)
        if msg.id:
            self._ids.add(msg.id)
        self._stored = self._writer.submit(
            latch_store.save_latch(
                latch_store.ESTOP,
                "",
                msg.engaged,
                msg.ts,
                msg.id,
                msg.reason,
                msg.source,
                time.time(),
                self._audited(msg, actor, client_source),
            ),
            want_result=True,
            after_rows=False,
        )
        self._writer.submit(
            repo.insert_event(
                time.time(),
                "estop" if msg.engaged else "estop_release",
                None,
                {"id": msg.id, "reason": msg.reason, "source": msg.source},
            )
        )
        self.push()

    def _audited(self, msg: EStop, actor: Actor | None, client_source: str) -> AfterStore | None:
        """The audit row written with the state's store: the API's caller's always; a broker e-stop's by the
        replica that stores it first; none for another replica's API e-stop (that replica audited it)."""
        action = "estop" if msg.engaged else "estop_release"
        if actor is not None:
            row = self._audit.row(actor, action, None, estop_audit.detail(msg, client_source))
            return estop_audit.audit_after_store(row, always=True)
        if estop_audit.made_by_a_server(self._key, msg):
            return None
        row = self._audit.row(estop_audit.broker_actor(msg), action, None, estop_audit.detail(msg, msg.source))
        return estop_audit.audit_after_store(row, always=False)

    async def engage(self, reason: str, source: str, actor: Actor, client_source: str = "") -> EStopEngaged:
        """Publish and latch at once; return once the latch is also stored (a broker that loses it gets it
        back from the server), with ``actor``'s audit row (an engage while engaged is counted in the
        e-stop's row)."""
        ts = time.time()
        msg = EStop(ts=ts, id=estop_audit.signed_id(self._key, ts, True), engaged=True, reason=reason, source=source)
        self._publisher.publish(self._topics.estop(), dumps(msg), qos=QOS_ESTOP, retain=True)
        self._apply(msg, actor, client_source)
        log.warning("E-STOP engaged (%s) by %s", reason or "no reason", source)
        await wait_stored(self._stored, "e-stop's state")
        robots = [r.id for r in self._registry.robots.values() if r.online]
        return EStopEngaged(id=msg.id or "", ts=msg.ts, engaged=True, robots=sorted(robots))

    async def release(self, reason: str, source: str, actor: Actor, client_source: str = "") -> EStopEngaged:
        ts = time.time()
        msg = EStop(ts=ts, id=estop_audit.signed_id(self._key, ts, False), engaged=False, reason=reason, source=source)
        self._publisher.publish(self._topics.estop(), dumps(msg), qos=QOS_ESTOP, retain=True)
        self._apply(msg, actor, client_source)
        log.warning("e-stop released by %s", source)
        await wait_stored(self._stored, "e-stop's state")
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
        """Our own publish's echo, another's e-stop (a replica, ``fleet-agent estop``), or the retained one
        after a (re)connection: taken when newer than ours, or when it latches (latches.py)."""
        self._on_broker = msg
        if replaces(self._stamp(), self.state.engaged, (msg.ts, msg.id or ""), msg.engaged):
            self._apply(msg)
        elif msg.id != self.state.id:
            log.warning("e-stop message older than the server's state ignored (%s, ts %.3f)", msg.id, msg.ts)

    def forget_broker(self) -> None:
        self._on_broker = None

    def put_back(self) -> int:
        """After a (re)connection's sync: publish our latch again if the broker lost it (never a release)."""
        on_broker = self._on_broker
        seen = None if on_broker is None else (on_broker.ts, on_broker.id or "")
        if not lost_by_broker(self._stamp(), self.state.engaged, seen) or self.state.ts is None:
            return 0
        msg = EStop(
            ts=self.state.ts, id=self.state.id, engaged=True, reason=self.state.reason, source=self.state.source
        )
        self._publisher.publish(self._topics.estop(), dumps(msg), qos=QOS_ESTOP, retain=True)
        self._on_broker = msg
        held = "nothing" if seen is None else "an older state"
        log.warning("E-STOP latched again on the broker, which held %s", held)
        return 1

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
