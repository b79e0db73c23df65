"""Per-robot stop latch ("hold this robot"): stopped, its drives refused until released.

Beside the fleet e-stop, for one robot. Like the e-stop, the state is a RETAINED message on the broker
(``{prefix}/{robot}/hold``) that the server subscribes to, so replicas agree; each state is also stored and
restored at start, and a hold the broker lost is published again at the next connection (latches.py has
the rules). The server refuses drives to a held robot (409 ``robot_held``); robots on the old framework that
listen on the shared command topic hear every drive sent there, so a hold on one of them blocks drives to
all of them (they are one unit).
"""

from __future__ import annotations

import concurrent.futures
import logging
import time
import uuid
from typing import Any

from backend.comms.base import Publisher
from backend.services.fleet.registry import Registry, RobotState
from backend.services.safety.latches import Stamp, lost_by_broker, replaces, wait_stored
from backend.store import latches as latch_store
from backend.store.writer import BatchWriter
from fleet_protocol import QOS_HOLD, RobotHold, Topics, dumps

log = logging.getLogger(__name__)


def _stamp(msg: RobotHold | None) -> Stamp | None:
    return None if msg is None else (msg.ts, msg.id or "")


class HoldService:
    def __init__(self, *, registry: Registry, publisher: Publisher, topics: Topics, writer: BatchWriter) -> None:
        self._registry = registry
        self._publisher = publisher
        self._topics = topics
        self._writer = writer
        #: robot id -> its hold, for held robots only (also robots not seen yet: a retained hold is kept)
        self.holds: dict[str, RobotHold] = {}
        #: robot id -> its newest state, held or released (what a message from the broker is compared with)
        self._latest: dict[str, RobotHold] = {}
        #: robot id -> the newest message seen on its topic since the broker link (re)connected
        self._on_broker: dict[str, RobotHold] = {}

    def restore(self, rows: list[dict[str, Any]]) -> None:
        """At start, before the broker link: the stored states (the broker may have lost them since)."""
        for row in rows:
            msg = RobotHold(
                held=row["engaged"], ts=row["ts"], id=row["latch_id"], reason=row["reason"], source=row["source"]
            )
            self._latest[row["robot_id"]] = msg
            if msg.held:
                self.holds[row["robot_id"]] = msg
                st = self._registry.get(row["robot_id"])
                if st is not None:
                    st.hold = msg
        if self.holds:
            log.warning("robots held (restored): %s", ", ".join(sorted(self.holds)))

    async def set(self, robot_id: str, held: bool, reason: str, source: str) -> RobotHold:
        """Publish and apply at once; return once the state is also stored (a broker that loses it gets it
        back from the server)."""
        msg = RobotHold(held=held, ts=time.time(), id=uuid.uuid4().hex, reason=reason, source=source)
        self._publisher.publish(self._topics.hold(robot_id), dumps(msg), qos=QOS_HOLD, retain=True)
        stored = self._adopt(robot_id, msg)
        log.warning(
            "robot %s %s by %s (%s)",
            robot_id,
            "held" if held else "released",
            source,
            reason or "-",
            extra={"robot_id": robot_id},
        )
        await wait_stored(stored, f"hold of {robot_id}")
        return msg

    def on_hold(self, robot_id: str, msg: RobotHold) -> None:
        """From the broker (retained on subscribe, another replica, our own :meth:`set` echoed): taken when
        newer than ours, or when it holds (latches.py)."""
        self._on_broker[robot_id] = msg
        latest = self._latest.get(robot_id)
        if replaces(_stamp(latest), latest is not None and latest.held, (msg.ts, msg.id or ""), msg.held):
            self._adopt(robot_id, msg)

    def _adopt(self, robot_id: str, msg: RobotHold) -> concurrent.futures.Future[Any] | None:
        """Take ``msg`` as the robot's state and store it; returns the store's future."""
        before = self._latest.get(robot_id)
        if before is not None and _stamp(before) == _stamp(msg) and before.held == msg.held:
            return None  # nothing changed (our own publish echoed back)
        self._latest[robot_id] = msg
        if msg.held:
            self.holds[robot_id] = msg
        else:
            self.holds.pop(robot_id, None)
        stored = self._writer.submit(
            latch_store.save_latch(
                latch_store.HOLD, robot_id, msg.held, msg.ts, msg.id, msg.reason, msg.source, time.time()
            ),
            want_result=True,
            after_rows=False,
        )
        if not msg.held and (before is None or not before.held):
            return stored  # released again: stored, nothing to tell
        self._registry.event(
            "hold" if msg.held else "hold_release", robot_id, {"reason": msg.reason, "source": msg.source}
        )
        st = self._registry.get(robot_id)
        if st is not None:
            st.hold = msg if msg.held else None
            self._registry.push(st)
        return stored

    def forget_broker(self) -> None:
        self._on_broker.clear()

    def put_back(self) -> int:
        """After a (re)connection's sync: publish each hold the broker lost again (never a release)."""
        count = 0
        for robot_id, msg in self.holds.items():
            seen = self._on_broker.get(robot_id)
            if lost_by_broker(_stamp(msg), True, _stamp(seen)):
                self._publisher.publish(self._topics.hold(robot_id), dumps(msg), qos=QOS_HOLD, retain=True)
                self._on_broker[robot_id] = msg
                log.warning("robot %s held again on the broker", robot_id, extra={"robot_id": robot_id})
                count += 1
        return count

    def blocking(self, st: RobotState, unit: list[str]) -> tuple[str, RobotHold] | None:
        """The hold that refuses a drive to ``st`` (its own, or one on a robot of its legacy unit)."""
        for rid in [st.id, *unit]:
            hold = self.holds.get(rid)
            if hold is not None:
                return rid, hold
        return None

    def attach(self, st: RobotState) -> None:
        """A robot (re)appearing in the registry shows the hold retained for it."""
        st.hold = self.holds.get(st.id)
