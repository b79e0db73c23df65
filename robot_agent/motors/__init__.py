"""Motor drivers behind one interface; the config's ``[motors] type`` picks one from the registry."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ValidationError

from robot_agent.motors.base import MotorConfigError, MotorDriver
from robot_agent.motors.gpio import GpioMotorConfig, GpioMotorDriver
from robot_agent.motors.none import NoMotorConfig, NoMotorDriver
from robot_agent.motors.sim import SimMotorConfig, SimMotorDriver
from robot_agent.sim.world import SimWorld

#: config ``type`` -> (config model, driver class)
MOTOR_REGISTRY: dict[str, tuple[type[BaseModel], type[MotorDriver]]] = {
    "sim": (SimMotorConfig, SimMotorDriver),
    "gpio": (GpioMotorConfig, GpioMotorDriver),
    "none": (NoMotorConfig, NoMotorDriver),
}


def validate_motor_config(raw: dict[str, Any], default: str = "sim") -> BaseModel:
    kind = raw.get("type", default)
    if kind not in MOTOR_REGISTRY:
        raise MotorConfigError(f"unknown motor type {kind!r} (known: {', '.join(MOTOR_REGISTRY)})")
    model, _ = MOTOR_REGISTRY[kind]
    try:
        return model.model_validate({**raw, "type": kind})
    except ValidationError as exc:
        raise MotorConfigError(f"bad [motors] config: {exc}") from None


def create_motor_driver(raw: dict[str, Any], world: SimWorld | None) -> MotorDriver:
    """The driver for ``[motors]``; without a ``type``: ``sim`` when simulating, else ``none``."""
    cfg = validate_motor_config(raw, "sim" if world is not None else "none")
    _, cls = MOTOR_REGISTRY[str(cfg.type)]  # type: ignore[attr-defined]
    return cls.create(cfg, world)


__all__ = [
    "MOTOR_REGISTRY",
    "MotorConfigError",
    "MotorDriver",
    "create_motor_driver",
    "validate_motor_config",
]
