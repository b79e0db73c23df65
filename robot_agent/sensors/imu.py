"""IMU: ``{"accel": [ax, ay, az] m/s^2, "gyro": [gx, gy, gz] rad/s}`` in the robot's body frame.

Sources: ``sim`` derives it from the simulated kinematics (plus optional Gaussian noise); ``legacy``
takes the seed's ``"ax,ay,az,gx,gy,gz"`` datagrams on UDP 5005.
"""

from __future__ import annotations

import random
from typing import Any, Literal

from pydantic import Field

from fleet_protocol import ImuData
from robot_agent.sensors.base import SensorConfig, SensorContext, SensorPlugin
from robot_agent.sensors.legacy_source import LegacyInput


class ImuConfig(SensorConfig):
    type: str = "imu"
    source: Literal["sim", "legacy"] = "sim"
    rate_hz: float = Field(default=10.0, gt=0.0, le=1000.0)
    #: Standard deviation of the simulated noise (same units as the values).
    noise: float = Field(default=0.0, ge=0.0, le=10.0)


class ImuPlugin(SensorPlugin):
    type_name = "imu"
    default_stream = "imu"
    config_model = ImuConfig
    payload_model = ImuData

    def __init__(self, config: SensorConfig, ctx: SensorContext) -> None:
        super().__init__(config, ctx)
        assert isinstance(config, ImuConfig)
        self.cfg = config
        self._legacy = LegacyInput("imu")

    async def start(self) -> None:
        if self.cfg.source == "sim" and self.ctx.world is None:
            raise RuntimeError("imu source 'sim' needs the simulated robot (run with --simulate)")
        if self.cfg.source == "legacy":
            await self._legacy.open(self)

    async def stop(self) -> None:
        self._legacy.close()

    async def read(self) -> dict[str, Any] | None:
        world = self.ctx.world
        assert world is not None
        accel, gyro = world.imu()
        if self.cfg.noise:
            accel = [a + random.gauss(0.0, self.cfg.noise) for a in accel]
            gyro = [g + random.gauss(0.0, self.cfg.noise) for g in gyro]
        return {"accel": accel, "gyro": gyro}

    async def run(self) -> None:
        if self.cfg.source == "legacy":
            await self._legacy.run(self)
        else:
            await super().run()
