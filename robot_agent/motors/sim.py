"""Simulated motors: set the wheel speeds of the :class:`SimWorld`."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import IO, Any, Literal

import orjson
from pydantic import BaseModel, ConfigDict

from robot_agent.motors.base import MotorConfigError, MotorDriver, clamp_unit
from robot_agent.sim.world import SimWorld


class SimMotorConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    type: Literal["sim"] = "sim"
    #: Simulate a motor fault (e.g. "overcurrent"): drive commands are then rejected by the gate.
    fault: str | None = None
    #: Append every set-point to this file as a JSON line ``{"t", "left", "right", "thread"}``, written by
    #: the thread that applied it at the moment it did: the record safety tests measure the motors with.
    trace_file: Path | None = None


class SimMotorDriver(MotorDriver):
    def __init__(self, world: SimWorld, fault: str | None = None, trace_file: Path | None = None) -> None:
        self.world = world
        self.fault = fault
        self.left = 0.0
        self.right = 0.0
        self._usage_lock = threading.Lock()
        self._usage_s = 0.0
        self._usage_mark = time.monotonic()
        self._trace: IO[bytes] | None = open(trace_file, "ab", buffering=0) if trace_file else None  # noqa: SIM115

    @classmethod
    def create(cls, config: Any, world: SimWorld | None) -> SimMotorDriver:
        if world is None:
            raise MotorConfigError("the sim motor driver needs the simulated world (run with --simulate)")
        assert isinstance(config, SimMotorConfig)
        return cls(world, config.fault, config.trace_file)

    def _record(self) -> None:
        if self._trace is not None:
            line = {"t": time.time(), "left": self.left, "right": self.right, "thread": threading.current_thread().name}
            self._trace.write(orjson.dumps(line) + b"\n")

    def wheel_usage_s(self) -> float:
        """Seconds of full-speed driving so far: the integral of the mean |set-point| (the sim battery)."""
        with self._usage_lock:
            now = time.monotonic()
            self._usage_s += (abs(self.left) + abs(self.right)) / 2 * (now - self._usage_mark)
            self._usage_mark = now
            return self._usage_s

    @property
    def motor_fault(self) -> bool | None:
        return bool(self.fault)

    def set(self, left: float, right: float) -> None:
        self.wheel_usage_s()  # account the old set-points up to now
        self.left, self.right = clamp_unit(left), clamp_unit(right)
        self.world.set_wheels(self.left, self.right)
        self._record()

    def stop(self) -> None:
        self.wheel_usage_s()
        self.left = self.right = 0.0
        self.world.set_wheels(0.0, 0.0)
        self._record()

    def operable(self) -> tuple[bool, str]:
        if self.fault:
            return False, f"simulated fault: {self.fault}"
        return True, ""

    def close(self) -> None:
        self.stop()
        if self._trace is not None:
            self._trace.close()
            self._trace = None
