"""A robot is ready for a mission only on what it has reported: ``/api/robots``' ``ready`` and a mission's start
use the same rule (``Registry.not_ready``)."""

from __future__ import annotations

import time

from backend.schemas.robots import PositionPublic
from backend.services.fleet.registry import Registry, RobotState


def test_a_robot_without_a_health_report_is_not_ready_until_its_clock_is_known() -> None:
    """A robot just online with a fix but no health report yet was called ready, and the mission started on
    it a moment later was refused 422 ("clock not synchronised") once its first health report came: the two
    disagreed for up to a second (seen when a test's robot came online faster)."""
    now = time.time()
    st = RobotState(id="r1", first_seen=now, online=True)
    st.position = PositionPublic(x=0.0, y=0.0, ts=now)
    assert Registry.not_ready(st, now) == ["no health report yet (clock not known)"]
    st.health = {"clock_offset_ms": 3.0}
    assert Registry.not_ready(st, now) == []
    st.health = {"cpu_percent": 5.0}  # a report without the clock: not synchronised yet
    assert Registry.not_ready(st, now) == ["clock not synchronised"]


def test_a_robot_of_the_old_framework_needs_no_health_report_to_be_judged() -> None:
    now = time.time()
    st = RobotState(id="seed", first_seen=now, online=True, legacy=True)
    st.position = PositionPublic(x=0.0, y=0.0, ts=now)
    assert Registry.not_ready(st, now) == ["old framework: no deadman or autonomy of its own"]


def test_a_robot_whose_filter_hears_no_poses_is_not_ready() -> None:
    """Its safety filter creeps and refuses new goals until the fleet's poses come: a mission started on it
    would only wait. ``null`` (the filter off, an older agent) does not hold it back."""
    now = time.time()
    st = RobotState(id="r1", first_seen=now, online=True)
    st.position = PositionPublic(x=0.0, y=0.0, ts=now)
    st.health = {"clock_offset_ms": 3.0, "hears_poses": False}
    assert Registry.not_ready(st, now) == ["hears no fleet poses: its safety filter creeps, and new goals wait"]
    for heard in (True, None):
        st.health = {"clock_offset_ms": 3.0, "hears_poses": heard}
        assert Registry.not_ready(st, now) == []
