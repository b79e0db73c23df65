"""Battery sources for the health sensor; ``[sensors.battery] type`` picks one. Adding a source is one
module plus one line in the registry."""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from robot_agent.sensors.battery.base import BatteryConfig, BatteryReading, BatterySource, NoBattery
from robot_agent.sensors.battery.hat_file import HatFileBattery
from robot_agent.sensors.battery.ina219 import Ina219Battery
from robot_agent.sensors.battery.sim import SimBattery

BATTERY_REGISTRY: dict[str, type[BatterySource]] = {
    "none": NoBattery,
    "ina219": Ina219Battery,
    "file": HatFileBattery,
    "sim": SimBattery,
}


def validate_battery_config(raw: dict[str, Any]) -> BatteryConfig:
    """The source's own config model, validated; ValueError names the problem."""
    kind = raw.get("type", "none")
    if kind not in BATTERY_REGISTRY:
        raise ValueError(f"unknown battery type {kind!r} (known: {', '.join(BATTERY_REGISTRY)})")
    try:
        return BATTERY_REGISTRY[kind].config_model.model_validate({**raw, "type": kind})
    except ValidationError as exc:
        raise ValueError(f"battery ({kind}): {exc}") from None


def create_battery_source(config: BatteryConfig, shared: dict[str, Any]) -> BatterySource:
    return BATTERY_REGISTRY[config.type](config, shared)


__all__ = [
    "BATTERY_REGISTRY",
    "BatteryConfig",
    "BatteryReading",
    "BatterySource",
    "create_battery_source",
    "validate_battery_config",
]
