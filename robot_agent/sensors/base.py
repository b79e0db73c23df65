"""The sensor plugin contract: a small base class every sensor implements.

A plugin declares its config model (``extra="forbid"``), the stream it publishes, its payload schema and
rate. The agent's supervisor runs each plugin in its own asyncio task: a plugin that raises is reported in
the robot's status and restarted with exponential backoff while the other sensors keep running.
"""

from __future__ import annotations

import asyncio
from abc import ABC
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field

if TYPE_CHECKING:
    from robot_agent.sim.world import SimWorld


class SensorConfig(BaseModel):
    """Base of every plugin's config. ``type`` picks the plugin in the registry."""

    model_config = ConfigDict(extra="forbid")

    type: str
    #: Stream name on the wire; defaults to the plugin's ``default_stream``.
    stream: str | None = None
    rate_hz: float = Field(default=20.0, gt=0.0, le=1000.0)
    enabled: bool = True


EmitFn = Callable[[str, dict[str, Any]], None]
EmitRetainedFn = Callable[[str, dict[str, Any]], None]
EmitBinaryFn = Callable[[str, bytes], None]


@dataclass
class SensorContext:
    """What a plugin may use: the robot id, the simulated world (sim only) and the publish hooks.

    ``emit(stream, data)`` publishes one telemetry message (the agent adds ts and seq);
    ``emit_retained`` publishes a retained telemetry message (e.g. lighthouse geometry);
    ``emit_camera`` publishes a binary camera frame payload; ``shared`` lets plugins share one
    resource (the camera capture) by key.
    """

    robot_id: str
    emit: EmitFn
    emit_retained: EmitRetainedFn
    emit_camera: EmitBinaryFn
    world: SimWorld | None = None
    shared: dict[str, Any] = field(default_factory=dict)


class SensorPlugin(ABC):
    """One sensor. Override :meth:`read` (sampled at ``rate_hz``) or :meth:`run` (own loop)."""

    type_name: ClassVar[str]
    default_stream: ClassVar[str]
    config_model: ClassVar[type[SensorConfig]] = SensorConfig
    #: Schema of the ``data`` object this plugin publishes (documentation and validation in tests).
    payload_model: ClassVar[type[BaseModel] | None] = None

    def __init__(self, config: SensorConfig, ctx: SensorContext) -> None:
        self.config = config
        self.ctx = ctx

    @property
    def stream(self) -> str:
        return self.config.stream or self.default_stream

    async def start(self) -> None:  # noqa: B027 - optional hook
        """Open the device. Raise if it is missing; the supervisor retries with backoff."""

    async def stop(self) -> None:  # noqa: B027 - optional hook
        """Release the device."""

    async def read(self) -> dict[str, Any] | None:
        """Take one sample; ``None`` means nothing to publish this tick."""
        raise NotImplementedError

    async def run(self) -> None:
        """Default loop: sample at ``rate_hz`` on a fixed schedule (no drift) and emit."""
        loop = asyncio.get_running_loop()
        period = 1.0 / self.config.rate_hz
        next_t = loop.time()
        while True:
            data = await self.read()
            if data is not None:
                self.ctx.emit(self.stream, data)
            next_t += period
            delay = next_t - loop.time()
            if delay < -period:  # fell far behind (slow read): resynchronise instead of bursting
                next_t = loop.time()
                delay = 0.0
            await asyncio.sleep(max(0.0, delay))
