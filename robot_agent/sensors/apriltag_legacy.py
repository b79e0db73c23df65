"""AprilTag detections from today's Mollusca AprilTag module (JSON on UDP 5007), passed through as
``{"raw": <the module's JSON>}`` on the ``apriltag_legacy`` stream (the ``apriltag`` stream is the new
detector's schema)."""

from __future__ import annotations

from pydantic import Field

from robot_agent.sensors.base import SensorConfig, SensorPlugin
from robot_agent.sensors.legacy_source import run_legacy


class LegacyAprilTagConfig(SensorConfig):
    type: str = "apriltag_legacy"
    rate_hz: float = Field(default=30.0, gt=0.0, le=1000.0)


class LegacyAprilTagPlugin(SensorPlugin):
    type_name = "apriltag_legacy"
    default_stream = "apriltag_legacy"
    config_model = LegacyAprilTagConfig

    async def run(self) -> None:
        await run_legacy(self, "apriltag")
