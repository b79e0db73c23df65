"""The twin on its own (backend/services/rehearsal/twin.py): a seed repeats a rehearsal exactly, another seed
changes it, and a plan that brings robots together is reported before anything moves."""

from __future__ import annotations

import copy
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
