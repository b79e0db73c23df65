"""Per-robot stop latch ("hold this robot"): stopped, its drives refused until released.

Beside the fleet e-stop, for one robot. Like the e-stop, the state is a RETAINED message on the broker
(``{prefix}/{robot}/hold``) that the server subscribes to, so replicas agree and a restart keeps it. The
server refuses drives to a held robot (409 ``robot_held``); robots on the old framework that listen on
the shared command topic hear every drive sent there, so a hold on one of them blocks drives to all of
them (they are one unit).
"""

from __future__ import annotations

import logging
import time

from backend.comms.base import Publisher
from backend.services.fleet.registry import Registry, RobotState
from fleet_protocol import QOS_HOLD, RobotHold, Topics, dumps

log = logging.getLogger(__name__)


class HoldService:
    def __init__(self, *, registry: Registry, publisher: Publisher, topics: Topics) -> None:
        self._registry = registry
        self._publisher = publisher
        self._topics = topics
        #: robot id -> its hold, for held robots only (also robots not seen yet: a retained hold is kept)
        self.holds: dict[str, RobotHold] = {}

    def set(self, robot_id: str, held: bool, reason: str, source: str) -> RobotHold:
        msg = RobotHold(held=held, ts=time.time(), reason=reason, source=source)
        self._publisher.publish(self._topics.hold(robot_id), dumps(msg), qos=QOS_HOLD, retain=True)
        self.on_hold(robot_id, msg)
        log.warning(
            "robot %s %s by %s (%s)",
            robot_id,
            "held" if held else "released",
            source,
            reason or "-",
            extra={"robot_id": robot_id},
        )
        return msg

    def on_hold(self, robot_id: str, msg: RobotHold) -> None:
        """From the broker (retained on subscribe, another replica) or our own :meth:`set`."""
        before = self.holds.get(robot_id)
        if msg.held:
            self.holds[robot_id] = msg
        else:
            self.holds.pop(robot_id, None)
        if (before is not None) == msg.held and (before is None or before.ts == msg.ts):
            return  # nothing changed (our own publish echoed back)
        self._registry.event(
            "hold" if msg.held else "hold_release", robot_id, {"reason": msg.reason, "source": msg.source}
        )
        st = self._registry.get(robot_id)
        if st is not None:
            st.hold = msg if msg.held else None
            self._registry.push(st)

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
