"""A stretch's separation figures for the run and mission routes: read on the readers' threads (the
database), computed on the planner's pool (CPU work, bounded by the caps of backend/services/runs/separation.py),
never on the event loop."""

from __future__ import annotations

from backend.api.exports import read
from backend.schemas.separation import SeparationStats
from backend.services.lifecycle import Services
from backend.services.runs.separation import MAX_AVOIDANCE_PER_ROBOT, from_samples, sample_cap
from backend.store.separation import read_samples
from fleet_protocol.neighbours import AVOIDANCE_STREAM

#: a site without one (or no site): the default of SiteUpdate
DEFAULT_MIN_SEPARATION_M = 0.3


async def separation_of(
    services: Services, robots: list[str], start: float, end: float, min_separation_m: float
) -> SeparationStats:
    """How close ``robots`` came to each other between ``start`` and ``end`` and how often their filters acted."""
    cap = sample_cap(len(robots))
    engine = services.readers.engine
    samples = await read(
        services, read_samples, engine, robots, start, end, cap, MAX_AVOIDANCE_PER_ROBOT, AVOIDANCE_STREAM
    )
    # queued, not refused: a summary waits its turn behind a plan (its own work is bounded)
    return await services.missions.planner.run_queued(from_samples, samples, min_separation_m, start)
