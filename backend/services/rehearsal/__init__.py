"""Rehearsal: a mission run first in a simulated twin of the fleet, on virtual time, and what it predicts
(docs/missions.md, "Rehearsal"). The twin is the server's mission service and the robots' own motion code on
the simulator: loop.py (virtual time), robots.py (the agent's parts), server.py (what stands in for the broker
and the database), measure.py (the figures), twin.py (one run), service.py (the live server's side)."""

from backend.services.rehearsal.service import MAX_SEEDS, RehearsalService, summarise
from backend.services.rehearsal.twin import RehearsalInput, RobotStart, rehearse

__all__ = ["MAX_SEEDS", "RehearsalInput", "RehearsalService", "RobotStart", "rehearse", "summarise"]
