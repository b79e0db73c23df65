"""Shared run loop for plugins fed by the legacy UDP inputs: publish each sample as it arrives."""

from __future__ import annotations

import asyncio
from typing import Any

from robot_agent.legacy.udp import get_hub
from robot_agent.sensors.base import SensorPlugin


async def run_legacy(plugin: SensorPlugin, kind: str) -> None:
    """Forward ``kind`` samples from the UDP hub to ``plugin``'s stream, at most ``rate_hz`` per second."""
    hub = get_hub(plugin.ctx.shared)
    queue: asyncio.Queue[dict[str, Any]] = await hub.subscribe(kind)
    loop = asyncio.get_running_loop()
    min_gap = 1.0 / plugin.config.rate_hz
    last = -1e9
    try:
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
    finally:
        hub.unsubscribe(kind, queue)
