"""Shared input for plugins fed by the legacy UDP inputs: publish each sample as it arrives."""

from __future__ import annotations

import asyncio
from typing import Any

from robot_agent.legacy.udp import LegacyUdpHub, get_hub
from robot_agent.sensors.base import SensorPlugin


class LegacyInput:
    """One plugin's subscription to one legacy UDP input (``imu``, ``position``, ``apriltag``).

    :meth:`open` belongs in the plugin's ``start()``: the port is bound (or its failure known) before the
    supervisor reports the sensor ok, so a sample sent as soon as the status says ok is not lost, and a
    taken port never shows as a brief ok. :meth:`run` forwards samples; :meth:`close` is for ``stop()``."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._hub: LegacyUdpHub | None = None
        self._queue: asyncio.Queue[dict[str, Any]] | None = None

    async def open(self, plugin: SensorPlugin) -> None:
        if self._queue is None:
            hub = get_hub(plugin.ctx.shared)
            self._queue = await hub.subscribe(self.kind)  # raises OSError when the port is taken
            self._hub = hub

    def close(self) -> None:
        if self._hub is not None and self._queue is not None:
            self._hub.unsubscribe(self.kind, self._queue)
        self._hub = self._queue = None

    async def run(self, plugin: SensorPlugin) -> None:
        """Forward samples to ``plugin``'s stream, at most ``rate_hz`` per second (the newest wins)."""
        await self.open(plugin)  # no-op after start(); kept for plugins that call run() alone
        queue = self._queue
        assert queue is not None
        loop = asyncio.get_running_loop()
        min_gap = 1.0 / plugin.config.rate_hz
        last = -1e9
        while True:
            sample = await queue.get()
            while not queue.empty():  # publish the newest when samples come faster than rate_hz
                sample = queue.get_nowait()
            gap = loop.time() - last
            if gap < min_gap:
                await asyncio.sleep(min_gap - gap)
                while not queue.empty():
                    sample = queue.get_nowait()
            last = loop.time()
            plugin.ctx.emit(plugin.stream, sample)
