"""The battery source contract: one small class per kind of battery monitor, picked by config ``type``."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, model_validator


@dataclass(frozen=True, slots=True)
class BatteryReading:
    """What a source measured; ``None`` where it measures nothing (never a made-up value)."""

    voltage_v: float | None = None
    percent: float | None = None
    current_a: float | None = None


NO_READING = BatteryReading()


class BatteryConfig(BaseModel):
    """Base of every source's config (``extra="forbid"``: a typo is an error, not a silent default)."""

    model_config = ConfigDict(extra="forbid")

    type: str


class VoltageRangeConfig(BatteryConfig):
    """A pack whose charge is estimated from its voltage: linear between empty and full, clamped."""

    #: pack voltage at 0 % and at 100 % (defaults: a 2S LiPo)
    empty_v: float = Field(default=6.4, gt=0.0, le=1000.0)
    full_v: float = Field(default=8.4, gt=0.0, le=1000.0)

    @model_validator(mode="after")
    def _check_range(self) -> VoltageRangeConfig:
        if self.full_v <= self.empty_v:
            raise ValueError(f"full_v ({self.full_v}) must be above empty_v ({self.empty_v})")
        return self

    def percent_of(self, voltage_v: float) -> float:
        frac = (voltage_v - self.empty_v) / (self.full_v - self.empty_v)
        return round(min(max(frac, 0.0), 1.0) * 100.0, 1)


class BatterySource(ABC):
    """Reads the battery. ``read`` runs once per health sample on the agent's loop: keep it short."""

    type_name: ClassVar[str]
    config_model: ClassVar[type[BatteryConfig]] = BatteryConfig

    def __init__(self, config: BatteryConfig, shared: dict[str, Any]) -> None:
        self.config = config
        self.shared = shared

    def open(self) -> None:  # noqa: B027 - optional hook
        """Open the device; raise when it is missing (the health sensor then reports the error)."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the device."""

    @abstractmethod
    def read(self) -> BatteryReading:
        """One reading; fields it cannot measure now are None."""


class NoBattery(BatterySource):
    """``type = "none"``: no battery monitor; battery fields are null."""

    type_name = "none"

    def read(self) -> BatteryReading:
        return NO_READING
