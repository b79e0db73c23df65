"""Another replica's rows of a mission, mirrored (backend/services/missions/replicas.py): read on the event loop
once per change, so never turned into geometry there."""

from __future__ import annotations

import copy
from typing import Any

import pytest
from shapely.geometry import box

from backend.services.missions.book import mission_from_row
from backend.services.missions.record import Mission, mission_row
from backend.services.missions.replicas import mirrored
from backend.services.missions.state import Coverage, MissionRobot, built_coverage, rings
from tests.support.missions import lawn_track

WIDTH = 0.2
PLAN = {"workable": rings(box(-5, -5, 5, 5)), "holes": [], "workable_area_m2": 100.0, "band_m": 0.25}


def row_of(tracks: dict[str, list[list[float]]], fraction: float, swept_m2: dict[str, float]) -> dict[str, Any]:
    """A running coverage mission's row as its owner, another replica, stored it."""
    robots = [MissionRobot(robot_id=rid, path=[[0.0, 0.0]], breaks=[1], track=t) for rid, t in tracks.items()]
    m = Mission(
        id="m1",
        name="long",
        type="coverage",
        state="running",
        robot_ids=list(tracks),
        params={"sweep_width_m": WIDTH, "overlap": 0.0},
        created_by="op",
        created_at=1.0,
        updated_at=2.0,
        plan=PLAN,
        robots=robots,
        coverage=Coverage([], [], WIDTH),
    )
    row = mission_row(m, full=True)
    row["progress"].update(covered_fraction=fraction, swept_m2=swept_m2)
    return {**row, "owner": "other-replica", "requested": None, "heartbeat_at": 2.0}


def long_tracks() -> dict[str, list[list[float]]]:
    return {
        "a": lawn_track(-4.9, 0.0, -4.9, 4.9, 0.25, seed=1),
        "b": lawn_track(0.1, 5.0, -4.9, 4.9, 0.25, seed=2),
    }


def unreadable(track: list[list[float]], keep: int) -> list[list[float]]:
    """The track with its points before the last ``keep`` made unreadable: reading them raises."""
    return [None] * (len(track) - keep) + track[len(track) - keep :]


def test_a_mirrored_row_shows_its_owners_figures_and_reads_none_of_its_tracks() -> None:
    """A mirror read every change of a running mission from its row and rebuilt the swept area from the whole
    tracks on the event loop (20,000 points here: the union of their buffers). It shows the figures the owner
    stored, builds nothing, and does not read a track point."""
    tracks = {rid: unreadable(t, 0) for rid, t in long_tracks().items()}
    m = mission_from_row(row_of(tracks, 0.4242, {"a": 20.0, "b": 22.5}))
    assert m.coverage.fraction == 0.4242 and m.coverage.per_robot == {"a": 20.0, "b": 22.5}
    assert m.coverage.deferred and m.coverage.grid is None  # its grid: built on the planner pool when asked


def test_a_mirror_whose_grid_was_built_goes_on_with_the_new_points_only() -> None:
    """Once this replica built a mirrored mission's grid (its coverage was asked here), the owner's next row
    adds its new points to it (as a step does), rather than building it again; a row of another plan starts
    over from its figures."""
    tracks = long_tracks()
    first = mission_from_row(row_of(tracks, 0.0, {}))
    first.coverage = built_coverage(first.coverage, [(r.robot_id, r.track, len(r.track)) for r in first.robots])
    assert first.coverage.fraction > 0.5  # every point of the first row marked
    grown = {rid: t + [[t[-1][0], t[-1][1] - 0.02 * i] for i in range(1, 4)] for rid, t in tracks.items()}
    whole = built_coverage(Coverage(PLAN["workable"], [], WIDTH), [(rid, t, len(t)) for rid, t in grown.items()])
    # the owner's next row: three points more per robot; those before the last one marked are unreadable
    row = row_of({rid: unreadable(t, 4) for rid, t in grown.items()}, whole.fraction, {})
    row["updated_at"] = 4.0
    second = mirrored(first, row)
    assert second.coverage is first.coverage and second.coverage.work == 6
    assert second.coverage.fraction == pytest.approx(whole.fraction, abs=1e-9)
    assert second.coverage.per_robot == pytest.approx(whole.per_robot, abs=1e-9)
    replanned = copy.deepcopy(row)
    replanned["plan"] = {**PLAN, "angle_rad": 1.57}
    third = mirrored(second, replanned)
    assert third.coverage is not second.coverage and third.coverage.deferred
    assert third.coverage.fraction == pytest.approx(whole.fraction)  # the figure its row holds
