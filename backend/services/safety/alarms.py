"""Alarms: the built-in rules (core/alarm_rules.py) watched on the robots' health, position and data,
each alarm ``active -> acknowledged -> cleared`` with every transition stored with who made it.

The rules run on every replica (each sees every robot's live telemetry); the database decides (a partial
unique index: one open alarm per robot and kind, and a clear that re-checks the alarm is still open), so
replicas never raise, clear or store a transition twice. Each replica re-reads the open alarms about once a
second (:meth:`AlarmService.sync`): an acknowledgement, override or clear made through another replica
reaches its banner, metrics and drive checks within that second. Battery
critical stops the robot and refuses its drives (409 ``battery_critical``) until the battery reads above the
threshold or an admin overrides it (audited).

The robots' own reports feed rules too: a geofence ``outside`` event raises ``geofence_breach`` (cleared by
``inside``), and each AprilTag frame with mapped wall tags (the site's tag map) is checked against the
Lighthouse fix of the same moment (``localization_disagreement``).

Missions (or any other service) react to alarms through :meth:`AlarmService.subscribe` (called on every
transition) and :meth:`AlarmService.critical_of` (the open critical alarms of a robot); alarms only notify.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

from backend.core.alarm_rules import RULES, merged_params
from backend.schemas import AlarmPublic
from backend.services.fleet.registry import Registry
from backend.services.live.hub import LiveHub
from backend.services.safety.alarm_checks import AlarmChecks, SiteTags
from backend.store import alarms as store
from backend.store.writer import BatchWriter

log = logging.getLogger(__name__)

#: a replica re-reads the open alarms this often (what another replica changed shows here)
SYNC_EVERY_S = 1.0

AlarmListener = Callable[[AlarmPublic], None]


class AlarmService(AlarmChecks):
    """The alarms' book: raise, clear, acknowledge, override, sync between replicas, and tell listeners (the rules
    that raise and clear them from telemetry: :class:`AlarmChecks`)."""

    def __init__(
        self,
        *,
        writer: BatchWriter,
        hub: LiveHub,
        registry: Registry,
        site: SiteTags | None = None,
    ) -> None:
        self._writer = writer
        self._hub = hub
        self._registry = registry
        #: the site's AprilTag map (tag id -> pose), read on each frame: a site that changes is seen at once
        self._site = site
        self._raise_listeners: list[Callable[[str, str], None]] = []
        #: robot -> robot ts since which its AprilTag and Lighthouse poses disagree
        self._disagree_since: dict[str, float] = {}
        self._listeners: list[AlarmListener] = []
        #: (robot, kind) -> the open alarm (active or acknowledged)
        self.open: dict[tuple[str, str], AlarmPublic] = {}
        self._pending: set[tuple[str, str]] = set()
        #: alarms cleared while their raise was being stored, and by whom: cleared once it is
        self._clear_after: dict[tuple[str, str], str] = {}
        self.rules: dict[str, dict[str, Any]] = {}
        #: robots whose battery-critical refusal an admin overrode (until that alarm clears)
        self.battery_override: set[str] = set()
        #: (robot, kind) -> how often this replica changed it (a database read older than a change is ignored)
        self._version: dict[tuple[str, str], int] = {}
        self._synced_at = 0.0
        #: the database writer's writes given up and telemetry rows not stored, as last alarmed
        self._store_seen = (0, 0)

    def load(self, open_rows: list[dict[str, Any]], rule_rows: list[dict[str, Any]]) -> None:
        for row in open_rows:
            alarm = alarm_public(row)
            self.open[(row["robot_key"], row["kind"])] = alarm
            if row["kind"] == "battery_critical" and (row["detail"] or {}).get("override_by"):
                self.battery_override.add(row["robot_key"])
        self.rules = {r["kind"]: r for r in rule_rows if r["kind"] in RULES}

    def params(self, kind: str) -> dict[str, float]:
        return merged_params(kind, (self.rules.get(kind) or {}).get("params"))

    def enabled(self, kind: str) -> bool:
        return bool((self.rules.get(kind) or {}).get("enabled", True))

    # -- transitions ----------------------------------------------------------------------------------------
    def raise_(self, robot_id: str, kind: str, message: str, detail: dict[str, Any]) -> None:
        key = (robot_id, kind)
        self._clear_after.pop(key, None)  # the newest reading wins over a clear asked while the raise is stored
        if key in self.open or key in self._pending or not self.enabled(kind):
            return
        rule = RULES[kind]
        self._pending.add(key)
        now = time.time()
        values = {
            "robot_key": robot_id,
            "kind": kind,
            "severity": rule.severity,
            "state": "active",
            "message": message,
            "detail": detail,
            "raised_at": now,
        }
        fut = self._writer.submit(store.raise_alarm(values), want_result=True, after_rows=False)
        if fut is None:
            self._pending.discard(key)
            return
        loop = asyncio.get_running_loop()
        fut.add_done_callback(lambda f: loop.call_soon_threadsafe(self._raised, key, f))
        log.warning("alarm %s on %s: %s", kind, robot_id, message, extra={"robot_id": robot_id})
        for listener in list(self._raise_listeners):
            try:
                listener(robot_id, kind)
            except Exception:
                log.exception("alarm raise listener %r failed on %s %s", listener, robot_id, kind)

    def on_raise(self, listener: Callable[[str, str], None]) -> None:
        """Call ``listener(robot_id, kind)`` the moment an alarm is raised, before it is stored: the command
        service stops a robot whose battery goes critical without waiting for the database."""
        self._raise_listeners.append(listener)

    def _raised(self, key: tuple[str, str], fut: Any) -> None:
        self._pending.discard(key)
        cleared_by = self._clear_after.pop(key, None)
        if fut.cancelled() or fut.exception() is not None:
            log.error("alarm %s not stored: %r", key, fut.exception() if not fut.cancelled() else "cancelled")
            return
        row = fut.result()
        alarm = alarm_public(row)
        self._set(key, alarm)
        self._changed(alarm)
        if cleared_by is not None:  # the reading went back while the raise was stored: it clears now
            self.clear(key[0], key[1], cleared_by)

    def clear(self, robot_id: str, kind: str, by: str = "system") -> None:
        key = (robot_id, kind)
        alarm = self.open.get(key)
        if alarm is None:
            if key in self._pending:  # raised a moment ago, its row not stored yet: cleared once it is
                self._clear_after[key] = by
            return
        self._set(key, None)
        now = time.time()
        self._writer.submit(store.clear_alarm(robot_id, kind, now, by), after_rows=False)
        alarm.state, alarm.cleared_at = "cleared", now
        self._changed(alarm)

    async def ack(self, alarm_id: int, by: str) -> AlarmPublic | None:
        fut = self._writer.submit(
            store.ack_alarm(alarm_id, time.time(), by), want_result=True, after_rows=False, retry=False
        )
        assert fut is not None
        row = await asyncio.wrap_future(fut)
        if row is None:
            return None
        alarm = alarm_public(row)
        key = (row["robot_key"], row["kind"])
        if key in self.open and row["cleared_at"] is None:
            self._set(key, alarm)
        self._changed(alarm)
        if RULES[row["kind"]].event and row["cleared_at"] is None:  # an event: seen to, so it is over
            self._set(key, alarm)
            self.clear(row["robot_key"], row["kind"], by)
        return alarm

    async def override_battery(self, robot_id: str, by: str) -> bool:
        """An admin lets a robot with a critical battery drive again until the alarm clears: stored with the
        alarm, so that every replica lets it drive. False: no battery-critical alarm is open."""
        alarm = self.open.get((robot_id, "battery_critical"))
        if alarm is None:
            return False
        fut = self._writer.submit(
            store.override_alarm(alarm.id, by, time.time()), want_result=True, after_rows=False, retry=False
        )
        assert fut is not None
        if not await asyncio.wrap_future(fut):
            return False
        self.battery_override.add(robot_id)
        return True

    def tick(self, now: float) -> None:
        super().tick(now)
        self._watch_store()

    def _watch_store(self) -> None:
        """What the database writer gave up since the last look raises a fleet-wide event alarm. Only once the
        writer can keep the alarm's own row: raised during the outage, it would be given up as well."""
        if not self._writer.has_room():
            return
        stats = self._writer.stats()
        writes, rows = int(stats["ops_dropped"]), int(stats["rows_dropped"]) + int(stats["rows_rejected"])
        seen_writes, seen_rows = self._store_seen
        self._store_seen = (writes, rows)
        if writes > seen_writes:
            n = writes - seen_writes
            why = f"{n} database writes given up (database unavailable, retry queue full): their rows are missing"
            self.raise_("", "store_writes_lost", why, {"writes": n, "total": writes})
        if rows > seen_rows:
            n = rows - seen_rows
            why = f"{n} telemetry rows not stored (unacked ones come again from the broker; refused ones are lost)"
            self.raise_("", "telemetry_not_stored", why, {"rows": n, "total": rows})

    # -- replicas ------------------------------------------------------------------------------------------
    def sync(self, now: float) -> None:
        """About once a second: re-read the open alarms, so that what another replica changed (an ack, an
        override, an event alarm it raised or a clear) shows here too."""
        if now - self._synced_at < SYNC_EVERY_S:
            return
        self._synced_at = now
        versions = dict(self._version)
        self._writer.read_then(store.read_open(), lambda rows: self._synced(rows, versions))

    def _synced(self, rows: list[dict[str, Any]], versions: dict[tuple[str, str], int]) -> None:
        found = {(r["robot_key"], r["kind"]): r for r in rows}
        for key in set(found) | set(self.open):
            if key in self._pending or self._version.get(key, 0) != versions.get(key, 0):
                continue  # changed here since the read was queued: this replica's view is newer
            mine, row = self.open.get(key), found.get(key)
            if row is not None and key[1] == "battery_critical" and (row["detail"] or {}).get("override_by"):
                self.battery_override.add(key[0])
            if row is None:
                if mine is not None:  # cleared through another replica
                    self._set(key, None)
                    mine.state, mine.cleared_at = "cleared", time.time()
                    self._changed(mine)
            elif mine is None or mine.id != row["id"] or mine.state != row["state"]:
                alarm = alarm_public(row)
                self._set(key, alarm)
                self._changed(alarm)

    def _set(self, key: tuple[str, str], alarm: AlarmPublic | None) -> None:
        """The one place ``open`` changes (and the version a database read is checked against)."""
        self._version[key] = self._version.get(key, 0) + 1
        if alarm is not None:
            self.open[key] = alarm
            return
        self.open.pop(key, None)
        if key[1] == "battery_critical":
            self.battery_override.discard(key[0])

    # -- reads ---------------------------------------------------------------------------------------------
    def blocks_drive(self, robot_id: str) -> str | None:
        """Why a drive to this robot is refused by an alarm (battery critical, not overridden), or None."""
        alarm = self.open.get((robot_id, "battery_critical"))
        if alarm is None or robot_id in self.battery_override:
            return None
        return (
            f"battery critical on {robot_id!r} ({alarm.message}): only stop passes until it reads above "
            "the threshold or an admin overrides it"
        )

    def of_robot(self, robot_id: str) -> list[AlarmPublic]:
        return [a for (rid, _), a in self.open.items() if rid == robot_id]

    def critical_of(self, robot_id: str) -> list[AlarmPublic]:
        """The robot's open critical alarms (active or acknowledged, not cleared): for a mission service that
        pauses a robot while one is open, and for readiness."""
        return [a for (rid, _), a in self.open.items() if rid == robot_id and a.severity == "critical"]

    def critical_kinds(self, robot_id: str) -> list[str]:
        """The kinds of the robot's critical alarms, open or being stored: a mission pauses its robot at once,
        before the stop a critical alarm may send ends the robot's goal (which would read as a failure)."""
        keys = set(self.open) | self._pending
        return sorted(
            kind for rid, kind in keys if rid == robot_id and (rule := RULES.get(kind)) and rule.severity == "critical"
        )

    def subscribe(self, listener: AlarmListener) -> Callable[[], None]:
        """Call ``listener`` (on the event loop) with every alarm transition: raised (``active``),
        ``acknowledged``, ``cleared``. Returns the unsubscribe function. A failing listener is logged, and
        neither the alarm nor the other listeners are affected."""
        self._listeners.append(listener)
        return lambda: self._listeners.remove(listener) if listener in self._listeners else None

    def active_counts(self) -> dict[str, int]:
        counts = {"info": 0, "warning": 0, "critical": 0}
        for alarm in self.open.values():
            if alarm.state == "active":
                counts[alarm.severity] = counts.get(alarm.severity, 0) + 1
        return counts

    def _changed(self, alarm: AlarmPublic) -> None:
        self._hub.publish_control({"type": "alarm", "alarm": alarm.model_dump(mode="json")}, alarm.robot_id)
        for listener in list(self._listeners):
            try:
                listener(alarm)
            except Exception:
                log.exception("alarm listener %r failed on %s %s", listener, alarm.kind, alarm.state)
        if alarm.robot_id:
            st = self._registry.get(alarm.robot_id)
            if st is not None:
                st.alarm_kinds = {kind: a.severity for (rid, kind), a in self.open.items() if rid == st.id}
                self._registry.push(st)


def alarm_public(row: dict[str, Any]) -> AlarmPublic:
    """An ``alarms`` row as the API shows it (``robot_key`` "" is a fleet-wide alarm: robot_id null)."""
    return AlarmPublic(**{"transitions": [], **row, "robot_id": row["robot_key"] or None})
