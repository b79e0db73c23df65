"""Lighthouse position: ``{"x","y","z"[,"yaw"]}`` metres/radians in the Lighthouse frame.

Sources: ``sim`` reads the simulated robot's pose; ``legacy`` takes what today's Lighthouse module sends
on UDP 5006. On start the plugin also publishes the base-station geometry, retained, on
``lighthouse_geometry`` (the agent re-publishes retained streams after a reconnect) so the dashboard can
draw the stations' frames.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import Field

from fleet_protocol import BaseStation, LighthouseGeometry, PositionData
from robot_agent.sensors.base import SensorConfig, SensorContext, SensorPlugin
from robot_agent.sensors.legacy_source import LegacyInput


def look_at_rotation(position: tuple[float, float, float], target: tuple[float, float, float]) -> list[list[float]]:
    """Rotation (columns = station x/y/z axes in the world) of a station whose x axis points at ``target``."""
    d = [t - p for t, p in zip(target, position, strict=True)]
    n = math.sqrt(sum(v * v for v in d)) or 1.0
    x = [v / n for v in d]
    up = [0.0, 0.0, 1.0]
    y = [up[1] * x[2] - up[2] * x[1], up[2] * x[0] - up[0] * x[2], up[0] * x[1] - up[1] * x[0]]
    ny = math.sqrt(sum(v * v for v in y)) or 1.0
    y = [v / ny for v in y]
    z = [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]]
    return [[round(x[i], 9), round(y[i], 9), round(z[i], 9)] for i in range(3)]


def default_base_stations() -> list[BaseStation]:
    """Two stations 2 m up at opposite corners of the 4 m x 4 m pool, looking at its centre."""
    out = []
    for i, p in enumerate(((-2.0, -2.0, 2.0), (2.0, 2.0, 2.0))):
        out.append(BaseStation(id=i, position=list(p), rotation=look_at_rotation(p, (0.0, 0.0, 0.0))))
    return out


class PositionConfig(SensorConfig):
    type: str = "position"
    source: Literal["sim", "legacy"] = "sim"
    base_stations: list[BaseStation] = Field(default_factory=default_base_stations, max_length=16)
    #: Stream the geometry is published on (retained); None = do not publish it.
    geometry_stream: str | None = "lighthouse_geometry"


class PositionPlugin(SensorPlugin):
    type_name = "position"
    default_stream = "position"
    config_model = PositionConfig
    payload_model = PositionData

    def __init__(self, config: SensorConfig, ctx: SensorContext) -> None:
        super().__init__(config, ctx)
        assert isinstance(config, PositionConfig)
        self.cfg = config
        self._legacy = LegacyInput("position")

    async def start(self) -> None:
        if self.cfg.source == "sim" and self.ctx.world is None:
            raise RuntimeError("position source 'sim' needs the simulated robot (run with --simulate)")
        if self.cfg.source == "legacy":
            await self._legacy.open(self)
        if self.cfg.geometry_stream:
            geometry = LighthouseGeometry(base_stations=self.cfg.base_stations)
            self.ctx.emit_retained(self.cfg.geometry_stream, geometry.model_dump(mode="json"))

    async def stop(self) -> None:
        self._legacy.close()

    async def read(self) -> dict[str, Any] | None:
        world = self.ctx.world
        assert world is not None
        p = world.lighthouse_fix()  # noisy, and None (nothing published) during a dropout
        if p is None:
            return None
        return {"x": p.x, "y": p.y, "z": 0.0, "yaw": p.yaw}

    async def run(self) -> None:
        if self.cfg.source == "legacy":
            await self._legacy.run(self)
        else:
            await super().run()
