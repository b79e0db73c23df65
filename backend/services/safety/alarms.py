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
import math
import time
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from backend.core.alarm_rules import RULES, merged_params
from backend.schemas import AlarmPublic
from backend.services.fleet.registry import RATE_WINDOW_S, Registry
from backend.services.live.hub import LiveHub
from backend.services.safety.tag_localization import robot_xy_from_tags
from backend.store import alarms as store
from backend.store.writer import BatchWriter
from fleet_protocol.motion import GEOFENCE_STREAM, SiteTag

log = logging.getLogger(__name__)

#: how far above a threshold a reading must be before a battery alarm clears (no flapping at the edge)
HYSTERESIS_PCT = 2.0
#: a localization disagreement clears below this fraction of its threshold (no flapping at the edge)
LOCALIZATION_CLEAR_FRACTION = 0.8
#: a replica re-reads the open alarms this often (what another replica changed shows here)
SYNC_EVERY_S = 1.0
#: the telemetry streams the rules read (the dispatcher hands only these over)
ALARM_STREAMS = frozenset({"health", GEOFENCE_STREAM, "apriltag"})

AlarmListener = Callable[[AlarmPublic], None]


class SiteTags(Protocol):
    """The site's wall tags, which the localization check compares the Lighthouse against (the site service;
    a sibling domain, so a protocol)."""

    def tag_map(self) -> Mapping[int, SiteTag]: ...


class AlarmService:
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
        self.rules: dict[str, dict[str, Any]] = {}
        #: robots whose battery-critical refusal an admin overrode (until that alarm clears)
        self.battery_override: set[str] = set()
        #: (robot, kind) -> how often this replica changed it (a database read older than a change is ignored)
        self._version: dict[tuple[str, str], int] = {}
        self._synced_at = 0.0

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

    # -- inputs -------------------------------------------------------------------------------------------
    def on_telemetry(self, robot_id: str, stream: str, ts: float, data: dict[str, Any]) -> None:
        """A message of one of ``ALARM_STREAMS`` (after the registry recorded it)."""
        if stream == "health":
            self.on_health(robot_id, data)
        elif stream == GEOFENCE_STREAM:
            self.on_geofence(robot_id, data)
        elif stream == "apriltag":
            self.on_apriltag(robot_id, ts, data)

    def on_geofence(self, robot_id: str, data: dict[str, Any]) -> None:
        """The robot's own geofence reports: out of the safe region raises, back in clears. A motion stopped
        or refused at the fence is the fence working (the geofence stream shows it), not a breach."""
        event = data.get("event")
        if event == "outside":
            x, y = _num(data.get("x")), _num(data.get("y"))
            where = f" at ({x:.2f}, {y:.2f}) m" if x is not None and y is not None else ""
            reason = str(data.get("reason") or "")[:200]
            self.raise_(
                robot_id,
                "geofence_breach",
                f"outside the safe region{where}{': ' + reason if reason else ''}",
                {"x": x, "y": y, "reason": reason, "site_version": data.get("site_version")},
            )
        elif event == "inside":
            self.clear(robot_id, "geofence_breach")

    def on_apriltag(self, robot_id: str, ts: float, data: dict[str, Any]) -> None:
        """One camera frame's detections against the Lighthouse fix of the same moment (robot clock)."""
        tags = self._site.tag_map() if self._site is not None else {}
        st = self._registry.get(robot_id)
        detections = data.get("detections")
        if not tags or st is None or st.position is None or not isinstance(detections, list):
            return
        p = self.params("localization_disagreement")
        pos = st.position
        if abs(pos.ts - ts) > p["max_skew_s"]:
            return  # no Lighthouse fix of that moment (a dropout): nothing to compare
        est = robot_xy_from_tags(tags, detections, pos.yaw, p["camera_forward_m"])
        if est is None:
            return
        x, y, n = est
        apart = math.hypot(x - pos.x, y - pos.y)
        if apart > p["above_m"]:
            since = self._disagree_since.setdefault(robot_id, ts)
            if ts - since >= p["for_s"]:
                self.raise_(
                    robot_id,
                    "localization_disagreement",
                    f"AprilTags and Lighthouse {apart * 100:.0f} cm apart (over {p['above_m'] * 100:g} cm)",
                    {
                        "apart_m": round(apart, 4),
                        "tags": n,
                        "tag_xy": [round(x, 4), round(y, 4)],
                        "lighthouse_xy": [round(pos.x, 4), round(pos.y, 4)],
                    },
                )
            return
        self._disagree_since.pop(robot_id, None)
        if apart <= p["above_m"] * LOCALIZATION_CLEAR_FRACTION:
            self.clear(robot_id, "localization_disagreement")

    def on_health(self, robot_id: str, data: dict[str, Any]) -> None:
        """A ``health`` sample: battery, temperature, Wi-Fi, clock and motor rules. Null fields say nothing."""
        st = self._registry.get(robot_id)
        if st is not None:
            st.health = data
        pct = _num(data.get("battery_pct"))
        if pct is not None:
            for kind in ("battery_critical", "battery_low"):
                below = self.params(kind)["below_pct"]
                if pct < below:
                    self.raise_(robot_id, kind, f"battery {pct:.0f} % (below {below:g} %)", {"battery_pct": pct})
                elif pct >= below + HYSTERESIS_PCT:
                    self.clear(robot_id, kind)
        self._threshold(robot_id, "cpu_hot", _num(data.get("cpu_temp_c")), "above_c", above=True, unit="°C")
        self._threshold(robot_id, "wifi_weak", _num(data.get("wifi_rssi_dbm")), "below_dbm", above=False, unit="dBm")
        offset = _num(data.get("clock_offset_ms"))
        self._threshold(
            robot_id, "clock_offset", abs(offset) if offset is not None else None, "above_ms", above=True, unit="ms"
        )
        fault = data.get("motor_fault")
        if isinstance(fault, bool):
            if fault:
                self.raise_(robot_id, "motor_fault", "the motor driver reports a fault", {})
            else:
                self.clear(robot_id, "motor_fault")

    def _threshold(self, robot_id: str, kind: str, value: float | None, key: str, *, above: bool, unit: str) -> None:
        if value is None:
            return
        limit = self.params(kind)[key]
        if (value > limit) if above else (value < limit):
            self.raise_(
                robot_id, kind, f"{value:g} {unit} ({'above' if above else 'below'} {limit:g} {unit})", {key: value}
            )
        else:
            self.clear(robot_id, kind)

    def data_lost(self, robot_id: str, stream: str, n: int, reason: str) -> None:
        """Telemetry lost for good (gap repair gave up): an event alarm. A gap being repaired is none."""
        self.raise_(
            robot_id,
            "data_gap",
            f"{n} {stream} messages lost for good ({reason})",
            {"stream": stream, "lost": n, "reason": reason},
        )

    def tick(self, now: float) -> None:
        """Position fix and message rate of every online robot."""
        after_s = self.params("no_position_fix")["after_s"]
        below_hz = self.params("low_rate")["below_hz"]
        for st in self._registry.robots.values():
            if not st.online or st.legacy:
                self.clear(st.id, "no_position_fix")
                self.clear(st.id, "low_rate")
                continue
            if "position" in st.capabilities.sensors and st.position is not None:
                if now - st.position.ts > after_s:
                    self.raise_(st.id, "no_position_fix", f"no position for {now - st.position.ts:.1f} s", {})
                else:
                    self.clear(st.id, "no_position_fix")
            if st.online_since is not None and now - st.online_since > 2 * RATE_WINDOW_S:
                rate = st.msg_rate(now)
                if rate < below_hz:
                    self.raise_(st.id, "low_rate", f"{rate:g} messages/s (below {below_hz:g})", {"rate": rate})
                else:
                    self.clear(st.id, "low_rate")

    # -- transitions ----------------------------------------------------------------------------------------
    def raise_(self, robot_id: str, kind: str, message: str, detail: dict[str, Any]) -> None:
        key = (robot_id, kind)
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
        if fut.cancelled() or fut.exception() is not None:
            log.error("alarm %s not stored: %r", key, fut.exception() if not fut.cancelled() else "cancelled")
            return
        row = fut.result()
        alarm = alarm_public(row)
        self._set(key, alarm)
        self._changed(alarm)

    def clear(self, robot_id: str, kind: str, by: str = "system") -> None:
        key = (robot_id, kind)
        alarm = self.open.get(key)
        if alarm is None:
            return
        self._set(key, None)
        now = time.time()
        self._writer.submit(store.clear_alarm(robot_id, kind, now, by), after_rows=False)
        alarm.state, alarm.cleared_at = "cleared", now
        self._changed(alarm)

    async def ack(self, alarm_id: int, by: str) -> AlarmPublic | None:
        fut = self._writer.submit(store.ack_alarm(alarm_id, time.time(), by), want_result=True, after_rows=False)
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
        fut = self._writer.submit(store.override_alarm(alarm.id, by, time.time()), want_result=True, after_rows=False)
        assert fut is not None
        if not await asyncio.wrap_future(fut):
            return False
        self.battery_override.add(robot_id)
        return True

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


def _num(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None
