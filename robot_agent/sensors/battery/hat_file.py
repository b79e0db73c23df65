"""A battery HAT (or UPS board) whose driver or daemon writes the battery state to a file.

``path`` is either a Linux ``power_supply`` directory (``/sys/class/power_supply/BAT0``: ``voltage_now``
in uV, ``capacity`` in %) or one file, read as the first shape that fits:
- a JSON object with ``voltage_v`` / ``voltage`` / ``battery_v`` (V) and ``capacity`` / ``percent`` /
  ``battery_pct`` (%);
- ``KEY=value`` lines (a power_supply ``uevent``: ``POWER_SUPPLY_VOLTAGE_NOW`` uV,
  ``POWER_SUPPLY_CAPACITY`` %);
- a single number, meaning what ``value`` says.
A missing file or a value that does not parse gives null fields (and nothing is guessed). Without a
capacity, the percentage comes from the voltage when ``empty_v`` and ``full_v`` are set.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import orjson
from pydantic import Field

from robot_agent.sensors.battery.base import NO_READING, BatteryConfig, BatteryReading, BatterySource

_JSON_VOLTAGE = ("voltage_v", "voltage", "battery_v")
_JSON_PERCENT = ("capacity", "percent", "battery_pct")


class HatFileConfig(BatteryConfig):
    type: str = "file"
    path: Path
    #: what a file holding a single number means
    value: Literal["voltage_v", "voltage_uv", "percent"] = "voltage_v"
    #: pack voltage at 0 % and 100 %, to derive the percentage when the file has only a voltage
    empty_v: float | None = Field(default=None, gt=0.0, le=1000.0)
    full_v: float | None = Field(default=None, gt=0.0, le=1000.0)


def _number(text: Any) -> float | None:
    try:
        v = float(text)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return None


def parse_power_supply_dir(path: Path) -> tuple[float | None, float | None]:
    """(volts, percent) of a sysfs power_supply directory."""
    uv = _number(_read_text(path / "voltage_now"))
    pct = _number(_read_text(path / "capacity"))
    return (None if uv is None else uv / 1e6), pct


def parse_battery_text(text: str, single_value: str = "voltage_v") -> tuple[float | None, float | None]:
    """(volts, percent) from a JSON object, ``KEY=value`` lines or one number (see the module docstring)."""
    if text.startswith("{"):
        try:
            obj = orjson.loads(text)
        except orjson.JSONDecodeError:
            return None, None
        if not isinstance(obj, dict):
            return None, None
        volts = next((v for k in _JSON_VOLTAGE if (v := _number(obj.get(k))) is not None), None)
        pct = next((v for k in _JSON_PERCENT if (v := _number(obj.get(k))) is not None), None)
        return volts, pct
    if "=" in text:
        pairs = dict(line.split("=", 1) for line in text.splitlines() if "=" in line)
        uv = _number(pairs.get("POWER_SUPPLY_VOLTAGE_NOW"))
        return (None if uv is None else uv / 1e6), _number(pairs.get("POWER_SUPPLY_CAPACITY"))
    v = _number(text)
    if v is None:
        return None, None
    if single_value == "percent":
        return None, v
    return (v / 1e6 if single_value == "voltage_uv" else v), None


class HatFileBattery(BatterySource):
    type_name = "file"
    config_model = HatFileConfig

    def __init__(self, config: Any, shared: dict[str, Any]) -> None:
        super().__init__(config, shared)
        assert isinstance(config, HatFileConfig)
        self.cfg = config

    def read(self) -> BatteryReading:
        path = self.cfg.path
        if path.is_dir():
            volts, pct = parse_power_supply_dir(path)
        else:
            text = _read_text(path)
            if text is None:
                return NO_READING
            volts, pct = parse_battery_text(text, self.cfg.value)
        if volts is not None and volts < 0:
            volts = None
        if pct is not None and not 0.0 <= pct <= 100.0:
            pct = None
        lo, hi = self.cfg.empty_v, self.cfg.full_v
        if pct is None and volts is not None and lo is not None and hi is not None and hi > lo:
            pct = round(min(max((volts - lo) / (hi - lo), 0.0), 1.0) * 100.0, 1)
        return BatteryReading(voltage_v=volts, percent=pct)
