"""Motion from the client: real server, broker and simulated agents (tests/support/client_motion.py)."""

from tests.support.client_motion import fleet, pool_site, server, sim_robots

__all__ = ["fleet", "pool_site", "server", "sim_robots"]
