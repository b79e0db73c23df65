"""The twin on its own (backend/services/rehearsal/twin.py): a seed repeats a rehearsal exactly, another seed
changes it, and a plan that brings robots together is reported before anything moves."""

from __future__ import annotations

import copy
import math
from typing import Any

from backend.services.rehearsal import RobotStart, rehearse
from tests.support.rehearsal import rehearsal_input

STARTS = [RobotStart("a", -0.9, -0.6, 1.57), RobotStart("b", -0.3, -0.6, 1.57), RobotStart("c", 0.3, -0.6, 1.57)]
SWEEP = {
    "type": "coverage",
    "robots": ["a", "b", "c"],
    "params": {"area": [[-1.0, -0.7], [0.6, -0.7], [0.6, 0.3], [-1.0, 0.3]], "sweep_width_m": 0.3},
}


def _figures(result: dict[str, Any]) -> dict[str, Any]:
    return result["predicted"]


def test_the_same_seed_gives_the_same_prediction_and_another_seed_another() -> None:
    inp = rehearsal_input(SWEEP, STARTS)
    first = rehearse(copy.deepcopy(inp), 11)
    again = rehearse(copy.deepcopy(inp), 11)
    other = rehearse(copy.deepcopy(inp), 12)
    assert first["predicted"]["outcome"] == "completed", first["predicted"]
    assert _figures(first) == _figures(again)
    assert _figures(first) != _figures(other)  # the seed reaches the disturbances: the check above could fail
    p = first["predicted"]
    assert 0.9 <= p["covered_fraction"] <= 1.0
    assert p["collisions"] == 0 and p["fence_violations"] == 0
    assert len(p["tracks"]["features"]) == 3
    assert set(p["per_robot"]) == {"a", "b", "c"}
    assert all(r["distance_m"] > 1.0 and r["status"] == "done" for r in p["per_robot"].values())


def _crossing(paths: dict[str, list[list[float]]]) -> dict[str, Any]:
    starts = [RobotStart("a", -1.0, 0.0, 0.0), RobotStart("b", 1.0, 0.02, 3.14)]
    body = {"type": "waypoints", "robots": ["a", "b"], "params": {"paths": paths}}
    return rehearse(rehearsal_input(body, starts), 5)["predicted"]


def test_a_plan_that_brings_robots_together_is_reported() -> None:
    """Two robots sent head-on along one line: the rehearsal reports the filter stepping in and how close they
    came; sent along two lines 1.2 m apart, nothing."""
    apart = _crossing({"a": [[-1.0, -0.6], [1.0, -0.6]], "b": [[1.0, 0.6], [-1.0, 0.6]]})
    assert apart["filter_interventions"] == 0 and apart["min_separation_m"] > 1.0, apart
    together = _crossing({"a": [[1.0, 0.0]], "b": [[-1.0, 0.0]]})
    assert together["filter_interventions"] > 0, together
    assert 0.25 <= together["min_separation_m"] < 0.5, together
    assert together["collisions"] == 0


def test_a_paused_mission_is_rehearsed_from_where_it_stopped() -> None:
    """Before a resume: the robots carry on from their paused places in the plan, as Resume would send them
    (a robot whose part is over stays done, holding its place against the current)."""
    inp = rehearsal_input(SWEEP, STARTS)
    m = inp.mission
    m.state, m.started_at = "paused", 0.0
    for r in m.robots:
        r.status = "paused"
    done = m.robots[0]
    done.status, done.index, done.reached = "done", len(done.path), len(done.path)
    p = rehearse(inp, 3)["predicted"]
    assert p["outcome"] == "completed", p
    robots = p["per_robot"]
    assert robots["a"]["status"] == "done" and robots["a"]["duration_s"] <= 0.5, robots  # its part was over
    assert all(robots[rid]["duration_s"] > 10.0 and robots[rid]["status"] == "done" for rid in ("b", "c")), robots


def test_a_robot_of_no_mission_in_the_way_is_a_neighbour_of_the_twin() -> None:
    """A robot standing by a waypoints robot's line (an old-framework one: no filter of its own) is kept clear
    of, counted in the closest approach, and reported on by nobody but the mission's robot. Whether the robot
    gets round it or ends blocked depends on the seed (1 in 4 seeds end blocked, docs/safety.md): either way the
    rehearsal says so."""
    starts = [RobotStart("a", -1.0, 0.0, 0.0), RobotStart("old", 0.0, 0.2, 1.57, in_mission=False, filtered=False)]
    body = {"type": "waypoints", "robots": ["a"], "params": {"paths": {"a": [[1.0, 0.0]]}}}
    p = rehearse(rehearsal_input(body, starts), 2)["predicted"]
    assert p["outcome"] == "completed" or (p["outcome"] == "failed" and p["blocked_legs"] == 1), p
    assert p["filter_interventions"] > 0 and p["closest_pair"] == ["a", "old"], p
    assert 0.25 <= p["min_separation_m"] < 0.6 and p["collisions"] == 0, p
    assert set(p["per_robot"]) == {"a"} and len(p["tracks"]["features"]) == 1


def test_a_formation_mission_is_rehearsed_with_the_servers_formation_law() -> None:
    """The leader's path and the fast loop's drives to the followers run in the twin as on the server: the
    mission ends after its duration with every robot done, the followers having gone round with the leader
    (each its slot's circle) and kept apart."""
    starts = [
        RobotStart("lead", 0.7, 0.0, 1.57),
        RobotStart("left", 0.4, -0.35, 1.57),
        RobotStart("right", 1.0, -0.35, 1.57),
    ]
    path = [[0.7 * math.cos(2 * math.pi * k / 32), 0.7 * math.sin(2 * math.pi * k / 32)] for k in range(32)]
    body = {
        "type": "formation",
        "robots": ["lead", "left", "right"],
        "params": {
            "leader": "lead",
            "path": path,
            "slots": {"left": [-0.35, 0.3], "right": [-0.35, -0.3]},
            "speed": 0.08,
            "duration_s": 12,
        },
    }
    p = rehearse(rehearsal_input(body, starts), 4)["predicted"]
    assert p["outcome"] == "completed" and 12.0 <= p["duration_s"] <= 13.0, p
    assert p["collisions"] == 0 and p["min_separation_m"] >= 0.3, p
    robots = p["per_robot"]
    assert all(r["status"] == "done" for r in robots.values()), robots
    lead = robots["lead"]["distance_m"]
    assert 0.7 < lead < 1.3, robots  # 12 s at 0.08 m/s
    # the inner slot's circle is about the leader's, the outer one's half as long again
    assert 0.7 * lead < robots["left"]["distance_m"] < 1.3 * lead, robots
    assert 1.2 * lead < robots["right"]["distance_m"] < 1.9 * lead, robots
