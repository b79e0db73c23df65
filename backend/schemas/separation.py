"""How close the robots came and how often their safety filters stepped in (issue 31, "Visible and counted"):
part of a run's summary and of a mission's report (docs/runs.md, Separation)."""

from __future__ import annotations

from pydantic import BaseModel, Field


class Approach(BaseModel):
    """Two robots' closest approach: centre to centre, at a stored sample of one of them."""

    robots: tuple[str, str]
    distance_m: float
    #: when (the robot's time stamp moved onto the server's clock, epoch s)
    ts: float


class PairSeparation(BaseModel):
    """One pair of robots over the stretch. Counts are episodes: consecutive samples under the distance."""

    robots: tuple[str, str]
    #: samples measured (each robot's samples where the other's position could be interpolated)
    samples: int
    closest_m: float | None = None
    closest_ts: float | None = None
    violations: int = 0
    violation_s: float = 0.0
    contacts: int = 0
    contact_s: float = 0.0


class RobotInterventions(BaseModel):
    """One robot's ``avoidance`` stream over the stretch."""

    #: episodes that started with ``active`` in the stretch
    count: int = 0
    duration_s: float = 0.0
    #: the smallest ``distance_m`` the filter reported
    min_distance_m: float | None = None
    #: more messages than read (the figures are of the first ones)
    truncated: bool = False


class SeparationStats(BaseModel):
    """Robotarium-style safety figures of a stretch of time, from the stored ``position`` samples (the other
    robot interpolated to each sample's time) and the ``avoidance`` streams."""

    #: a violation is an episode under this (the site's ``min_separation_m``)
    min_separation_m: float
    #: a contact is an episode under this (two body radii)
    contact_m: float
    #: the closest approach of any pair; null when no pair could be measured
    closest: Approach | None = None
    violations: int = 0
    violation_s: float = 0.0
    contacts: int = 0
    contact_s: float = 0.0
    pairs: list[PairSeparation] = Field(default_factory=list)
    #: the safety filters' interventions, over all robots and per robot
    interventions: int = 0
    intervention_s: float = 0.0
    #: the smallest distance to a neighbour any filter reported
    intervention_min_distance_m: float | None = None
    interventions_by_robot: dict[str, RobotInterventions] = Field(default_factory=dict)
    #: positions kept per robot (a long run: every ``step``-th stored sample, see ``step``)
    samples: dict[str, int] = Field(default_factory=dict)
    #: 1: every stored sample; more: a long run thinned to bound the work (closest approach may be missed)
    step: dict[str, int] = Field(default_factory=dict)
