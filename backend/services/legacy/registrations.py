"""Which robots may speak on the old framework's topics: only those an admin named.

The old framework cannot authenticate: its robots publish anonymously on shared topics and name themselves in
the payload, so anything that may write those topics could otherwise speak for any robot (or turn a robot of
the new framework into an old one). So the legacy bridge stores data only for registered robots, and a
robot's own status never makes it legacy. An admin registers them (REST, the dashboard, ``fleet-server robots
legacy-add``); they are kept in ``robots.legacy`` (robots the server knew as legacy before stay registered),
and every replica re-reads them about every :data:`SYNC_EVERY_S` seconds so a change made on one (or with
the CLI) applies on all.
"""

from __future__ import annotations

import logging
import time
from typing import Protocol

from backend.services.fleet.registry import Registry, RobotState
from backend.store import legacy as store
from backend.store.writer import BatchWriter
from fleet_protocol import LegacyListensOn

log = logging.getLogger(__name__)

#: seconds between two re-reads of the registrations (changes made on another replica or by the CLI)
SYNC_EVERY_S = 2.0


class NotLegacy(Exception):
    """The robot cannot be registered: it is online with the agent (the new framework)."""


class Stopper(Protocol):
    """What the registrations need of the legacy relay: an unregistered robot is told to stop first."""

    def stop(self, st: RobotState) -> None: ...


class LegacyRegistrations:
    def __init__(self, *, registry: Registry, writer: BatchWriter, relay: Stopper) -> None:
        self._registry = registry
        self._writer = writer
        self._relay = relay
        self._synced_at = 0.0
        #: bumped on every local change, so a re-read queued before it does not undo it
        self._version = 0

    def registered(self) -> list[str]:
        return sorted(st.id for st in self._registry.robots.values() if st.legacy)

    def register(self, robot_id: str, listens_on: LegacyListensOn, by: str) -> RobotState:
        """Let ``robot_id`` speak on the old framework's topics (stored; applied here at once)."""
        st = self._registry.get(robot_id)
        if st is not None and st.online and not st.legacy:
            raise NotLegacy(f"robot {robot_id!r} is online with the agent: it is not on the old framework")
        self._version += 1
        now = time.time()
        self._writer.submit(store.register(robot_id, listens_on, now))
        st = self._apply(robot_id, listens_on, now)
        log.warning("robot %s registered as on the old framework (%s topic) by %s", robot_id, listens_on, by)
        self._registry.event("legacy_registered", robot_id, {"listens_on": listens_on, "by": by})
        return st

    def unregister(self, robot_id: str, by: str) -> RobotState | None:
        """Refuse the robot's messages on the old topics from now on; if it was driving, it hears ``stop``."""
        self._version += 1
        self._writer.submit(store.unregister(robot_id))
        st = self._drop(robot_id)
        if st is not None:
            log.warning("robot %s no longer registered as on the old framework (by %s)", robot_id, by)
            self._registry.event("legacy_unregistered", robot_id, {"by": by})
        return st

    def _apply(self, robot_id: str, listens_on: LegacyListensOn, now: float) -> RobotState:
        st = self._registry.ensure(robot_id, now)
        unit_changed = not st.legacy or st.legacy_listens_on != listens_on
        st.legacy, st.legacy_listens_on = True, listens_on
        if unit_changed:
            self._push_legacy()
        return st

    def _drop(self, robot_id: str) -> RobotState | None:
        st = self._registry.get(robot_id)
        if st is None or not st.legacy:
            return st
        self._relay.stop(st)
        st.legacy = False
        self._registry.set_online(st, False, time.time(), "legacy-unregistered")
        self._push_legacy()
        self._registry.push(st)
        return st

    def _push_legacy(self) -> None:
        """A shared command topic makes its robots one unit: each member's view changes with it."""
        for other in self._registry.robots.values():
            if other.legacy:
                self._registry.push(other)

    # -- replicas ------------------------------------------------------------------------------------------
    def sync(self, now: float) -> None:
        """Every few seconds: re-read the registrations (made on another replica, or with the CLI)."""
        if now - self._synced_at < SYNC_EVERY_S:
            return
        self._synced_at = now
        version = self._version
        self._writer.read_then(store.read_registered(), lambda rows: self._synced(rows, version))

    def _synced(self, rows: dict[str, str], version: int) -> None:
        if version != self._version:
            return  # changed here since the read was queued: this replica's view is newer
        for robot_id, listens_on in rows.items():
            st = self._registry.get(robot_id)
            wanted: LegacyListensOn = "own" if listens_on == "own" else "shared"
            if st is None or not st.legacy or st.legacy_listens_on != wanted:
                log.info("robot %s registered as on the old framework elsewhere (%s topic)", robot_id, wanted)
                self._apply(robot_id, wanted, time.time())
        for st in list(self._registry.robots.values()):
            if st.legacy and st.id not in rows:
                log.info("robot %s unregistered from the old framework elsewhere", st.id)
                self._drop(st.id)
