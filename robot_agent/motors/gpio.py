"""Two DC motors on an H-bridge driven by gpiozero PWM (works on the Raspberry Pi 5 via lgpio).

Each motor has a forward and a backward PWM pin (and optionally an enable pin). An optional fault input
(e.g. a driver's nFAULT line) makes the motors not operable, which the command gate reports. gpiozero is
imported only when this driver is created, so the agent runs without it in simulation.
"""

from __future__ import annotations

import logging
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from robot_agent.motors.base import MotorDriver, clamp_unit

log = logging.getLogger(__name__)


class GpioMotorConfig(BaseModel):
    """``[motors] type = "gpio"``: BCM pin numbers."""

    model_config = ConfigDict(extra="forbid")

    type: Literal["gpio"] = "gpio"
    left_forward: int = Field(ge=0, le=53)
    left_backward: int = Field(ge=0, le=53)
    right_forward: int = Field(ge=0, le=53)
    right_backward: int = Field(ge=0, le=53)
    left_enable: int | None = Field(default=None, ge=0, le=53)
    right_enable: int | None = Field(default=None, ge=0, le=53)
    pwm_frequency: float = Field(default=1000.0, gt=0, le=100_000)
    #: Swap a motor's direction when it is mounted mirrored.
    invert_left: bool = False
    invert_right: bool = False
    #: Input pin of the driver's fault line; when active the motors are not operable.
    fault_pin: int | None = Field(default=None, ge=0, le=53)
    fault_active_low: bool = True
    #: gpiozero pin factory name ("lgpio" on the Pi 5); None = gpiozero's default.
    pin_factory: str | None = None


class GpioMotorDriver(MotorDriver):
    def __init__(self, config: GpioMotorConfig) -> None:
        from gpiozero import DigitalInputDevice, Motor

        self.config = config
        factory = None
        if config.pin_factory:
            import importlib

            names = {
                "lgpio": ("gpiozero.pins.lgpio", "LGPIOFactory"),
                "rpigpio": ("gpiozero.pins.rpigpio", "RPiGPIOFactory"),
                "pigpio": ("gpiozero.pins.pigpio", "PiGPIOFactory"),
                "native": ("gpiozero.pins.native", "NativeFactory"),
                "mock": ("gpiozero.pins.mock", "MockFactory"),
            }
            mod, cls = names[config.pin_factory]
            factory = getattr(importlib.import_module(mod), cls)()
        self._fault_error: str | None = None
        self._motors: list[Any] = []
        self._fault_in: Any = None
        try:
            for fwd, back, en in (
                (config.left_forward, config.left_backward, config.left_enable),
                (config.right_forward, config.right_backward, config.right_enable),
            ):
                m = Motor(fwd, back, enable=en, pwm=True, pin_factory=factory)
                m.forward_device.frequency = config.pwm_frequency
                m.backward_device.frequency = config.pwm_frequency
                self._motors.append(m)
            if config.fault_pin is not None:
                self._fault_in = DigitalInputDevice(
                    config.fault_pin, pull_up=config.fault_active_low, pin_factory=factory
                )
        except Exception:
            self.close()
            raise

    @classmethod
    def create(cls, config: Any, world: Any) -> GpioMotorDriver:
        assert isinstance(config, GpioMotorConfig)
        return cls(config)

    @property
    def motors(self) -> list[Any]:
        return list(self._motors)

    def _apply(self, motor: Any, value: float) -> None:
        if value > 0:
            motor.forward(value)
        elif value < 0:
            motor.backward(-value)
        else:
            motor.stop()

    def set(self, left: float, right: float) -> None:
        left, right = clamp_unit(left), clamp_unit(right)
        if self.config.invert_left:
            left = -left
        if self.config.invert_right:
            right = -right
        try:
            self._apply(self._motors[0], left)
            self._apply(self._motors[1], right)
        except Exception as exc:
            self._fault_error = f"gpio error: {exc}"
            self.stop()
            raise

    def stop(self) -> None:
        for m in self._motors:
            try:
                m.stop()
            except Exception as exc:  # a closed/broken device must not keep the other motor running
                log.error("motor stop failed: %s", exc)
                self._fault_error = f"gpio error: {exc}"

    def operable(self) -> tuple[bool, str]:
        if len(self._motors) != 2 or any(m.closed for m in self._motors):
            return False, "motor driver closed"
        if self._fault_error:
            return False, self._fault_error
        if self._fault_in is not None and self._fault_in.is_active:
            return False, f"driver fault line active (pin {self.config.fault_pin})"
        return True, ""

    @property
    def motor_fault(self) -> bool | None:
        """A GPIO error, or the fault line when one is configured; None without a fault pin and error."""
        if self._fault_error:
            return True
        if self._fault_in is None:
            return None
        return bool(self._fault_in.is_active)

    def close(self) -> None:
        self.stop()
        for dev in [*self._motors, self._fault_in]:
            if dev is not None:
                try:
                    dev.close()
                except Exception as exc:
                    log.debug("closing %s: %s", dev, exc)
