"""AprilTag detections from today's Mollusca AprilTag module (JSON on UDP 5007), passed through as
``{"raw": <the module's JSON>}`` on the ``apriltag_legacy`` stream (the ``apriltag`` stream is the new
detector's schema)."""

from __future__ import annotations

from pydantic import Field

from robot_agent.sensors.base import SensorConfig, SensorContext, SensorPlugin
from robot_agent.sensors.legacy_source import LegacyInput


class LegacyAprilTagConfig(SensorConfig):
    type: str = "apriltag_legacy"
    rate_hz: float = Field(default=30.0, gt=0.0, le=1000.0)


class LegacyAprilTagPlugin(SensorPlugin):
    type_name = "apriltag_legacy"
    default_stream = "apriltag_legacy"
    config_model = LegacyAprilTagConfig

    def __init__(self, config: SensorConfig, ctx: SensorContext) -> None:
        super().__init__(config, ctx)
        self._legacy = LegacyInput("apriltag")

    async def start(self) -> None:
        await self._legacy.open(self)

    async def stop(self) -> None:
        self._legacy.close()

    async def run(self) -> None:
        await self._legacy.run(self)
