"""Whether a server is watching: the server replicas' heartbeats, as the motion runner's goals need them.

A goal starts and keeps going only while a server beat within ``HEARTBEAT_SILENCE_S``; a goal that names its
``supervisor`` needs that replica's beat (another replica's does not keep it going). Kept apart from the
runner because it is its own small state (the last beat of each replica), read on every supervision tick.
"""

from __future__ import annotations

from fleet_protocol import HEARTBEAT_SILENCE_S
from robot_agent.motion.clock import Clock

#: server replicas whose last beat is remembered
MAX_SERVERS = 16


class ServerBeats:
    def __init__(self, clock: Clock) -> None:
        self._clock = clock
        self.last_at: float | None = None
        self.last_server: str | None = None
        #: when each server replica last beat (a goal naming its supervisor needs that replica's beat)
        self.by_server: dict[str, float] = {}

    def heard(self, server_id: str) -> None:
        """A heartbeat from ``server_id`` arrived now."""
        self.last_at = self._clock.monotonic()
        self.last_server = server_id
        self.by_server[server_id] = self.last_at
        if len(self.by_server) > MAX_SERVERS:  # ids of replicas long gone are forgotten, oldest first
            del self.by_server[min(self.by_server, key=self.by_server.__getitem__)]

    def supervised(self, server: str | None = None) -> bool:
        """A server beat within HEARTBEAT_SILENCE_S: any, or the replica ``server``."""
        hb = self._last(server)
        return hb is not None and self._clock.monotonic() - hb <= HEARTBEAT_SILENCE_S

    def silence(self, server: str | None) -> str:
        """How long it has been quiet, in the words of a failed goal's ack."""
        hb = self._last(server)
        silent = "ever" if hb is None else f"{self._clock.monotonic() - hb:.2f} s"
        return f"no heartbeat from server {server} for {silent}" if server else f"no server heartbeat for {silent}"

    def _last(self, server: str | None) -> float | None:
        return self.last_at if server is None else self.by_server.get(server)
