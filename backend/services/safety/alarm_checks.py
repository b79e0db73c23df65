"""The alarm checks on the robots' telemetry: health (battery, temperature, Wi-Fi, clock, motor), the robot's
own geofence reports, AprilTags against the Lighthouse, lost data, and each robot's fix and message rate.
They raise and clear; the book of alarms (alarms.py) stores, syncs and tells."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, Protocol

from backend.services.fleet.registry import RATE_WINDOW_S, Registry
from backend.services.safety.tag_localization import robot_xy_from_tags
from fleet_protocol.motion import GEOFENCE_STREAM, SiteTag

#: how far above a threshold a reading must be before a battery alarm clears (no flapping at the edge)
HYSTERESIS_PCT = 2.0
#: a localization disagreement clears below this fraction of its threshold (no flapping at the edge)
LOCALIZATION_CLEAR_FRACTION = 0.8
#: the telemetry streams the rules read (the dispatcher hands only these over)
ALARM_STREAMS = frozenset({"health", GEOFENCE_STREAM, "apriltag"})


class SiteTags(Protocol):
    """The site's wall tags, which the localization check compares the Lighthouse against (the site service;
    a sibling domain, so a protocol)."""

    def tag_map(self) -> Mapping[int, SiteTag]: ...


class AlarmChecks(ABC):
    """The checks, reading the registry and the site's tags; what they raise or clear goes to the book."""

    _registry: Registry
    _site: SiteTags | None
    #: robot -> robot ts since which its AprilTag and Lighthouse poses disagree
    _disagree_since: dict[str, float]

    @abstractmethod
    def params(self, kind: str) -> dict[str, float]: ...

    @abstractmethod
    def raise_(self, robot_id: str, kind: str, message: str, detail: dict[str, Any]) -> None: ...

    @abstractmethod
    def clear(self, robot_id: str, kind: str, by: str = "system") -> None: ...

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


def _num(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None
