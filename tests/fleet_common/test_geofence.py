"""The geofence's rule for goals, shared by the server and the robot (fleet_common/geofence.py): points in,
out, in the margin, in a keep-out or its margin; legs that cross a keep-out; a loop's closing leg; goals as the
server checks them; and shapely imported only when a region is built."""

from __future__ import annotations

import subprocess
import sys

import pytest

from fleet_common.geofence import SafeRegion

SQUARE = [[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]
KEEPOUT = [[0.5, -0.5], [1.0, -0.5], [1.0, 0.5], [0.5, 0.5]]
MARGIN = 0.15


@pytest.fixture(scope="module")
def region() -> SafeRegion:
    return SafeRegion(SQUARE, [KEEPOUT], MARGIN)


def test_points_in_out_in_the_margin_and_in_a_keepout(region: SafeRegion) -> None:
    assert region.point_problem(0.0, 0.0) is None
    assert region.point_problem(-1.8, 1.8) is None  # 0.2 m from two sides: inside the margin's line
    # the exact words: the server's 422 and the robot's refusal carry them, clients and tests read them
    assert region.point_problem(2.5, 0.0) == "(2.500, 0.000) is outside the boundary"
    assert region.point_problem(1.9, 0.0) == "(1.900, 0.000) is within the 0.15 m margin of the boundary"
    assert region.point_problem(0.75, 0.0) == "(0.750, 0.000) is inside keep-out 0 (or within its 0.15 m margin)"
    assert region.point_problem(0.4, 0.0) == "(0.400, 0.000) is inside keep-out 0 (or within its 0.15 m margin)"
    assert region.point_problem(0.3, 0.0) is None  # 0.2 m from the keep-out: clear of its margin
    assert "outside the boundary" in (region.point_problem(0.0, -2.0001) or "")


def test_the_keepout_index_is_the_sites() -> None:
    second = [[-1.0, -1.0], [-0.5, -1.0], [-0.5, -0.5], [-1.0, -0.5]]
    region = SafeRegion(SQUARE, [KEEPOUT, second], MARGIN)
    assert "inside keep-out 1 " in (region.point_problem(-0.75, -0.75) or "")
    assert "inside keep-out 0 " in (region.point_problem(0.75, 0.0) or "")


def test_no_margin_and_no_keepouts() -> None:
    region = SafeRegion(SQUARE)
    assert region.margin == 0.0 and region.keepouts == [] and region.grown_keepouts == []
    assert region.point_problem(1.99, 1.99) is None
    assert region.point_problem(2.01, 0.0) == "(2.010, 0.000) is outside the boundary"


def test_a_point_is_a_goal_exactly_when_it_is_in_the_safe_region(region: SafeRegion) -> None:
    from shapely.geometry import Point

    steps = [i / 10 for i in range(-22, 23)]
    for x in steps:
        for y in steps:
            assert (region.point_problem(x, y) is None) == region.safe.contains(Point(x, y)), (x, y)


def test_paths_points_first_then_legs(region: SafeRegion) -> None:
    ok = [(-1.0, -1.0), (-1.0, 1.0), (0.0, 1.2)]
    assert region.path_problem(ok) is None
    assert region.path_problem([(0.0, 0.0), (3.0, 0.0)]) == "waypoint 1: (3.000, 0.000) is outside the boundary"
    # every point inside, but the leg crosses the keep-out
    assert region.path_problem([(0.0, 0.0), (1.5, 0.0)]) == (
        "the leg from waypoint 0 leaves the safe region (crosses a keep-out or the margin)"
    )
    # a leg that only grazes the keep-out's margin leaves the safe region too
    assert "leg from waypoint 1" in (region.path_problem([(0.0, 1.0), (0.0, 0.6), (1.5, 0.6)]) or "")
    # a bad point is named before a bad leg
    assert (region.path_problem([(0.0, 0.0), (1.5, 0.0), (0.75, 0.0)]) or "").startswith("waypoint 2: ")
    # a repeated point is no leg; lists work as well as tuples
    assert region.path_problem([[0.0, 0.0], [0.0, 0.0], [0.0, 1.0]]) is None
    assert region.path_problem([(0.3, 0.2)]) is None


def test_a_loops_closing_leg_counts(region: SafeRegion) -> None:
    loop = [(0.0, -1.0), (1.5, -1.0), (1.5, 1.0)]
    assert region.path_problem(loop) is None
    assert region.path_problem(loop, closed=False) is None
    assert region.path_problem(loop, closed=True) == (
        "the leg from waypoint 2 leaves the safe region (crosses a keep-out or the margin)"
    )
    assert region.path_problem([(0.0, 0.0), (0.0, 1.0)], closed=True) is None  # two points: no closing leg


def test_goals_as_the_server_checks_them(region: SafeRegion) -> None:
    assert region.goal_problem("goto", {"x": 0.0, "y": 0.0}) is None
    assert region.goal_problem("goto", {"x": 2.5, "y": 0.0, "yaw": 1.0}) == "(2.500, 0.000) is outside the boundary"
    assert "keep-out 0" in (region.goal_problem("goto", {"x": 0.4, "y": 0}) or "")  # ints are coordinates too
    ok = [[-1.0, -1.0], [-1.0, 1.0], [0.0, 1.2]]
    assert region.goal_problem("follow_path", {"waypoints": ok, "loop": False}) is None
    assert "leg from waypoint 0" in (region.goal_problem("follow_path", {"waypoints": [[0, 0], [1.5, 0]]}) or "")
    loop = [[0.0, -1.0], [1.5, -1.0], [1.5, 1.0]]
    assert region.goal_problem("follow_path", {"waypoints": loop}) is None  # no "loop": not a loop
    assert region.goal_problem("follow_path", {"waypoints": loop, "loop": False}) is None
    assert "leg from waypoint 2" in (region.goal_problem("follow_path", {"waypoints": loop, "loop": True}) or "")
    bad = region.goal_problem("follow_path", {"waypoints": [[0.0, 0.0], [3.0, 0.0]]})
    assert bad == "waypoint 1: (3.000, 0.000) is outside the boundary"
    with pytest.raises(ValueError, match="not a goal"):
        region.goal_problem("drive", {"linear": 0.1})


def test_the_grown_keepouts_are_built_once_not_on_each_check(monkeypatch: pytest.MonkeyPatch) -> None:
    from shapely.geometry.base import BaseGeometry

    region = SafeRegion(SQUARE, [KEEPOUT], MARGIN)
    assert region.grown_keepouts[0].contains(region.keepouts[0])

    def no_buffer(*_: object, **__: object) -> None:
        raise AssertionError("buffered while checking")

    monkeypatch.setattr(BaseGeometry, "buffer", no_buffer)
    assert "keep-out 0" in (region.point_problem(0.4, 0.0) or "")
    assert "leg from waypoint 0" in (region.goal_problem("follow_path", {"waypoints": [[0, 0], [1.5, 0]]}) or "")
    assert region.goal_problem("goto", {"x": 0.0, "y": 0.0}) is None


def test_shapely_is_imported_when_a_region_is_built_not_with_the_module() -> None:
    code = (
        "import sys\n"
        "import fleet_common, fleet_common.geofence\n"
        "bad = [m for m in ('shapely', 'numpy') if m in sys.modules]\n"
        "assert not bad, bad\n"
        "fleet_common.geofence.SafeRegion([[0, 0], [1, 0], [1, 1]], [], 0.1)\n"
        "assert 'shapely' in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
