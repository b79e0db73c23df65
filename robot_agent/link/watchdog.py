"""Stops the motors when the broker link goes silent while the robot drives.

TCP and MQTT keepalive notice a dead link only after seconds (a Wi-Fi dropout leaves the socket open),
which is far too long for a moving robot. While a drive is active the agent publishes a small ping to its
own ``ping`` topic every ``period_s`` and listens to it; when no echo has come back for ``silence_s`` it
stops the motors (the drive is ended with reason "link silent"). Idle robots send nothing.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import time
from collections.abc import Callable

from fleet_protocol import LINK_PING_PERIOD_S, LINK_SILENCE_S

log = logging.getLogger(__name__)


class LinkWatchdog:
    def __init__(
        self,
        driving: Callable[[], bool],
        send_ping: Callable[[bytes], None],
        on_silence: Callable[[str], None],
        period_s: float = LINK_PING_PERIOD_S,
        silence_s: float = LINK_SILENCE_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._driving = driving
        self._send = send_ping
        self._on_silence = on_silence
        self.period_s = period_s
        self.silence_s = silence_s
        self._clock = clock
        self._counter = 0
        self._last_echo: float | None = None  # None: not watching (idle)
        self.trips = 0  # times the watchdog stopped the motors

    def on_echo(self, payload: bytes) -> None:
        if len(payload) == 8 and self._last_echo is not None:
            self._last_echo = self._clock()

    def tick(self) -> None:
        """One period: start/stop watching with the drive state, send a ping, trip on silence."""
        now = self._clock()
        if not self._driving():
            self._last_echo = None
            return
        if self._last_echo is None:
            self._last_echo = now  # a drive just started: give the first echo a full window
        elif now - self._last_echo > self.silence_s:
            self.trips += 1
            log.warning("no echo from the broker for %.2f s while driving: motors stopped", now - self._last_echo)
            self._last_echo = None
            self._on_silence("link silent")
            return
        self._counter += 1
        try:
            self._send(struct.pack(">Q", self._counter))
        except Exception:
            log.exception("link ping failed")

    async def run(self) -> None:
        while True:
            await asyncio.sleep(self.period_s)
            self.tick()
