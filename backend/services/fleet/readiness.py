"""Whether a robot is fit to go: one rule for ``/api/robots``' ``ready`` and a mission's start."""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleet_protocol import PROTOCOL_VERSION

if TYPE_CHECKING:
    from backend.services.fleet.registry import RobotState

READY_FIX_S = 0.5
READY_CLOCK_MS = 20.0


def not_ready(st: RobotState, now: float) -> list[str]:
    """Why the robot is not fit to go (empty: it is): each failed condition, in words."""
    reasons: list[str] = []
    if not st.online:
        return ["offline"]
    if st.legacy:
        reasons.append("old framework: no deadman or autonomy of its own")
    if st.position is None or now - st.position.ts > READY_FIX_S:
        reasons.append(f"no position fix within {READY_FIX_S:g} s")
    if "battery_critical" in st.alarm_kinds or "battery_low" in st.alarm_kinds:
        reasons.append("battery below the threshold")
    health = st.health or {}
    offset = health.get("clock_offset_ms")
    if not st.legacy:
        if isinstance(offset, int | float) and not isinstance(offset, bool):
            if abs(offset) > READY_CLOCK_MS:
                reasons.append(f"clock offset {offset:.0f} ms (over {READY_CLOCK_MS:g} ms)")
        elif st.health is not None:
            reasons.append("clock not synchronised")
        else:  # nothing says yet whether its clock is synchronised: ready only once its health says so
            reasons.append("no health report yet (clock not known)")
    if health.get("hears_poses") is False:
        reasons.append("hears no fleet poses: its safety filter creeps, and new goals wait")
    if health.get("motor_fault") is True or "motor_fault" in st.alarm_kinds:
        reasons.append("motors not operable (driver fault)")
    critical = sorted(k for k, sev in st.alarm_kinds.items() if sev == "critical")
    if critical:
        reasons.append("critical alarm: " + ", ".join(critical))
    if st.protocol_version is not None and st.protocol_version > PROTOCOL_VERSION:
        reasons.append(f"protocol version {st.protocol_version} not supported (server speaks {PROTOCOL_VERSION})")
    return reasons
