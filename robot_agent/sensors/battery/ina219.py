"""An INA219 current/power monitor on I2C (smbus2), in the battery's high side.

Registers (TI INA219 datasheet, SBOS448): 0x01 shunt voltage, a signed 16-bit value with an LSB of 10 uV
whatever the PGA setting; 0x02 bus voltage, bits 15..3 with an LSB of 4 mV (bit 1 CNVR, bit 0 OVF). Both
are sent most significant byte first. The pack voltage is the bus voltage (measured at VIN-, the load side
of the shunt) plus the shunt voltage; the current is the shunt voltage over the shunt resistance, computed
here, so the chip's calibration register is left alone (it may be shared with other software).
smbus2 is imported when the source opens, so the simulator runs without it.
"""

from __future__ import annotations

from typing import Any, Protocol

from pydantic import Field

from robot_agent.sensors.battery.base import BatteryReading, BatterySource, VoltageRangeConfig

REG_SHUNT_VOLTAGE = 0x01
REG_BUS_VOLTAGE = 0x02
SHUNT_LSB_V = 10e-6
BUS_LSB_V = 4e-3


class I2CBus(Protocol):
    """The part of ``smbus2.SMBus`` this source uses (tests pass a fake bus with recorded registers)."""

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]: ...

    def close(self) -> None: ...


class Ina219Config(VoltageRangeConfig):
    type: str = "ina219"
    #: I2C bus number (/dev/i2c-N; 1 on the Pi's header)
    bus: int = Field(default=1, ge=0, le=255)
    #: 7-bit address (0x40 with A0 = A1 = GND)
    address: int = Field(default=0x40, ge=0x03, le=0x77)
    #: shunt resistance, ohms (0.1 on the common breakout boards)
    shunt_ohms: float = Field(default=0.1, gt=0.0, le=100.0)


def shunt_voltage_v(raw: int) -> float:
    """Shunt voltage register value (unsigned 16-bit as read) -> volts (two's complement, 10 uV LSB)."""
    signed = raw - 0x10000 if raw & 0x8000 else raw
    return signed * SHUNT_LSB_V


def bus_voltage_v(raw: int) -> float:
    """Bus voltage register value -> volts (bits 15..3, 4 mV LSB)."""
    return (raw >> 3) * BUS_LSB_V


class Ina219Battery(BatterySource):
    type_name = "ina219"
    config_model = Ina219Config

    def __init__(self, config: Any, shared: dict[str, Any], bus: I2CBus | None = None) -> None:
        super().__init__(config, shared)
        assert isinstance(config, Ina219Config)
        self.cfg = config
        self._bus: I2CBus | None = bus

    def open(self) -> None:
        if self._bus is None:
            from smbus2 import SMBus  # the "pi" extra

            self._bus = SMBus(self.cfg.bus)

    def close(self) -> None:
        if self._bus is not None:
            self._bus.close()
            self._bus = None

    def _register(self, reg: int) -> int:
        assert self._bus is not None, "open() first"
        msb, lsb = self._bus.read_i2c_block_data(self.cfg.address, reg, 2)
        return (msb << 8) | lsb

    def read(self) -> BatteryReading:
        shunt_v = shunt_voltage_v(self._register(REG_SHUNT_VOLTAGE))
        pack_v = bus_voltage_v(self._register(REG_BUS_VOLTAGE)) + shunt_v
        return BatteryReading(
            voltage_v=round(pack_v, 5),  # the shunt LSB is 10 uV
            percent=self.cfg.percent_of(pack_v),
            current_a=round(shunt_v / self.cfg.shunt_ohms, 5),
        )
