"""The built-in alarm rules: what each watches, its severity and its default thresholds.

A rule is either a **condition** (raised while it holds, cleared when it no longer does, e.g. battery low)
or an **event** (raised when something happened that cannot un-happen, e.g. data lost for good: cleared once
acknowledged). Thresholds come from here, overridden by an admin with ``PUT /api/alarm-rules``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

Severity = Literal["info", "warning", "critical"]


@dataclass(frozen=True)
class Rule:
    kind: str
    severity: Severity
    description: str
    params: dict[str, float] = field(default_factory=dict)
    #: an event alarm clears when acknowledged; a condition alarm when its condition is gone
    event: bool = False


#: raised by the missions service; it only notifies (the mission re-plans the robot's area itself)
OFFLINE_IN_MISSION = "offline_in_mission"
#: raised fleet-wide by the loop watchdog (core/loopwatch.py) for a stall of the server's event loop
LOOP_STALL = "loop_stall"

RULES: dict[str, Rule] = {
    r.kind: r
    for r in (
        Rule("battery_low", "warning", "battery below `below_pct`", {"below_pct": 20.0}),
        Rule(
            "battery_critical",
            "critical",
            "battery below `below_pct`: the robot is stopped and its drives refused until it reads above, or an "
            "admin overrides it",
            {"below_pct": 8.0},
        ),
        Rule("cpu_hot", "warning", "CPU temperature above `above_c`", {"above_c": 75.0}),
        Rule("wifi_weak", "warning", "Wi-Fi signal below `below_dbm`", {"below_dbm": -75.0}),
        Rule(
            "clock_offset", "warning", "clock offset beyond `above_ms` (command expiry rests on it)", {"above_ms": 20.0}
        ),
        Rule("motor_fault", "critical", "the motor driver reports a fault"),
        Rule("no_position_fix", "warning", "online, but no position for `after_s`", {"after_s": 2.0}),
        Rule("low_rate", "warning", "online, but fewer than `below_hz` messages a second", {"below_hz": 1.0}),
        Rule("data_gap", "warning", "telemetry lost for good (a seq gap that could not be repaired)", event=True),
        Rule(
            OFFLINE_IN_MISSION,
            "critical",
            "went offline while in a running mission (its area went to the others; it drifts unsupervised)",
            event=True,
        ),
        Rule(
            "geofence_breach",
            "warning",
            "the robot reports itself outside the site's safe region (geofence `outside`); clears on `inside`",
        ),
        Rule(
            "localization_disagreement",
            "warning",
            "the pose from the mapped AprilTags and the Lighthouse pose differ by more than `above_m` for `for_s` "
            "(frames matched to a Lighthouse fix within `max_skew_s`; the camera `camera_forward_m` ahead of the "
            "robot's centre)",
            {"above_m": 0.10, "for_s": 1.0, "max_skew_s": 0.25, "camera_forward_m": 0.0},
        ),
        Rule("frames_quota", "warning", "a run stopped keeping camera frames: the frame store is full", event=True),
        Rule(
            "store_writes_lost",
            "critical",
            "the database writer gave up writes (audit, commands, events): the database was unavailable and its "
            "retry queue (FLEET_WRITER_RETRY_MAX) full",
            event=True,
        ),
        Rule(
            "telemetry_not_stored",
            "warning",
            "the database writer could not keep telemetry (its queue or retry buffer full: left unacked, the "
            "broker delivers it again) or the database refused rows (bad data: lost)",
            event=True,
        ),
        Rule(
            LOOP_STALL,
            "warning",
            "the server's event loop stalled for 0.2 s or more: the heartbeat, the REST e-stop, command acks and "
            "every live view waited that long (the log names where the loop was stuck)",
            event=True,
        ),
    )
}


def merged_params(kind: str, override: dict[str, Any] | None) -> dict[str, float]:
    """The rule's defaults with an admin's values on top (only known keys, as numbers)."""
    params = dict(RULES[kind].params)
    for key, value in (override or {}).items():
        if key in params:
            params[key] = float(value)
    return params
