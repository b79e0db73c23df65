"""Sensor plugins. The registry maps a config ``type`` to its plugin class: adding a sensor is one new
module plus one line here (see docs/adding-a-sensor.md)."""

from __future__ import annotations

from robot_agent.sensors.apriltag import AprilTagPlugin
from robot_agent.sensors.apriltag_legacy import LegacyAprilTagPlugin
from robot_agent.sensors.base import SensorConfig, SensorContext, SensorPlugin
from robot_agent.sensors.camera import CameraPlugin
from robot_agent.sensors.health import HealthPlugin
from robot_agent.sensors.imu import ImuPlugin
from robot_agent.sensors.position import PositionPlugin

SENSOR_REGISTRY: dict[str, type[SensorPlugin]] = {
    "position": PositionPlugin,
    "imu": ImuPlugin,
    "apriltag_legacy": LegacyAprilTagPlugin,
    "camera": CameraPlugin,
    "apriltag": AprilTagPlugin,
    "health": HealthPlugin,
}

__all__ = ["SENSOR_REGISTRY", "SensorConfig", "SensorContext", "SensorPlugin"]
