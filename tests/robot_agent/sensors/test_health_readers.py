"""The health stream's readers against recorded hardware: a fake I2C bus with recorded INA219 registers,
power_supply / HAT files, /proc/net/wireless and ``iw`` output written by the test. Missing sources give
null fields, never a value."""

from __future__ import annotations

import asyncio
import math
import stat
from pathlib import Path
from typing import Any

import pytest

from fleet_protocol import STREAM_SCHEMAS, HealthData, ProtocolError, decode_telemetry, dumps
from robot_agent.sensors.battery import BATTERY_REGISTRY, validate_battery_config
from robot_agent.sensors.battery.hat_file import HatFileBattery, parse_battery_text
from robot_agent.sensors.battery.ina219 import (
    REG_BUS_VOLTAGE,
    REG_SHUNT_VOLTAGE,
    Ina219Battery,
    Ina219Config,
    bus_voltage_v,
    shunt_voltage_v,
)
from robot_agent.sensors.sysinfo import read_cpu_temp_c
from robot_agent.sensors.wifi import WifiReader, parse_iw_link, parse_proc_net_wireless
from tests.support.procs import wait_until


class FakeSMBus:
    """Stands in for ``smbus2.SMBus``: answers block reads from recorded register words (MSB first, as
    the INA219 sends them) and records which device and register were read."""

    def __init__(self, address: int, registers: dict[int, int]) -> None:
        self.address = address
        self.registers = registers
        self.reads: list[tuple[int, int, int]] = []
        self.closed = False
        self.fail: OSError | None = None

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        self.reads.append((i2c_addr, register, length))
        if self.fail is not None:
            raise self.fail
        if i2c_addr != self.address:
            raise OSError(121, "Remote I/O error")  # what the kernel answers for an absent device
        word = self.registers[register]
        return [word >> 8, word & 0xFF]

    def close(self) -> None:
        self.closed = True


# -- INA219 ------------------------------------------------------------------------------------------------
def test_ina219_register_maths_matches_the_datasheet() -> None:
    # SBOS448 table 7 (shunt voltage register, PGA /8): 7D00h is +320.00 mV, 8300h is -320.00 mV; 0 is 0.
    assert shunt_voltage_v(0x7D00) == pytest.approx(0.320)
    assert shunt_voltage_v(0x8300) == pytest.approx(-0.320)
    assert shunt_voltage_v(0x0000) == 0.0
    assert shunt_voltage_v(0xFFFF) == pytest.approx(-10e-6)  # one LSB below zero
    # Bus voltage register: full scale 32 V is 8000 (1F40h) in bits 15..3; 16 V is 4000 (0FA0h).
    assert bus_voltage_v(0x1F40 << 3) == pytest.approx(32.0)
    assert bus_voltage_v(0x0FA0 << 3) == pytest.approx(16.0)
    # CNVR (bit 1) and OVF (bit 0) are flags, not part of the value.
    assert bus_voltage_v((0x0FA0 << 3) | 0b11) == pytest.approx(16.0)


def test_ina219_reads_pack_voltage_current_and_percentage_from_the_bus() -> None:
    # A 2S pack under load: bus 7.900 V (1975 x 4 mV, CNVR set), shunt 12.34 mV (1234 x 10 uV).
    bus = FakeSMBus(0x41, {REG_BUS_VOLTAGE: (1975 << 3) | 0b10, REG_SHUNT_VOLTAGE: 1234})
    cfg = validate_battery_config({"type": "ina219", "address": 0x41, "shunt_ohms": 0.1, "empty_v": 6.4, "full_v": 8.4})
    src = Ina219Battery(cfg, {}, bus=bus)
    src.open()  # a given bus is used as is: no smbus2 import, no /dev/i2c
    r = src.read()
    assert r.voltage_v == pytest.approx(7.900 + 0.01234)  # high side: bus (load side) + shunt drop
    assert r.current_a == pytest.approx(0.01234 / 0.1)
    assert r.percent == pytest.approx(round((7.91234 - 6.4) / (8.4 - 6.4) * 100, 1))
    assert {(a, reg) for a, reg, _ in bus.reads} == {(0x41, REG_SHUNT_VOLTAGE), (0x41, REG_BUS_VOLTAGE)}
    assert all(n == 2 for _, _, n in bus.reads)
    src.close()
    assert bus.closed


def test_ina219_percentage_is_clamped_and_charging_current_is_negative() -> None:
    over = FakeSMBus(0x40, {REG_BUS_VOLTAGE: 2200 << 3, REG_SHUNT_VOLTAGE: 0xFF38})  # 8.8 V, -2.00 mV
    r = Ina219Battery(Ina219Config(), {}, bus=over).read()
    assert r.percent == 100.0 and r.current_a == pytest.approx(-0.02)
    flat = FakeSMBus(0x40, {REG_BUS_VOLTAGE: 1500 << 3, REG_SHUNT_VOLTAGE: 0})  # 6.0 V
    assert Ina219Battery(Ina219Config(), {}, bus=flat).read().percent == 0.0


def test_ina219_without_the_device_fails_to_open_with_the_bus_named() -> None:
    src = Ina219Battery(validate_battery_config({"type": "ina219", "bus": 250}), {})
    with pytest.raises(OSError) as info:  # smbus2 opens /dev/i2c-250, which no machine has
        src.open()
    assert "i2c-250" in str(info.value)


def test_battery_config_errors_are_clear() -> None:
    with pytest.raises(ValueError, match="unknown battery type 'lead'"):
        validate_battery_config({"type": "lead"})
    with pytest.raises(ValueError, match="full_v"):
        validate_battery_config({"type": "ina219", "empty_v": 8.0, "full_v": 7.0})
    with pytest.raises(ValueError, match="adress"):
        validate_battery_config({"type": "ina219", "adress": 0x40})  # a typo is an error
    assert set(BATTERY_REGISTRY) == {"none", "ina219", "file", "sim"}


# -- battery HAT files --------------------------------------------------------------------------------------
def _file_source(path: Path, **kw: Any) -> HatFileBattery:
    src = BATTERY_REGISTRY["file"](validate_battery_config({"type": "file", "path": str(path), **kw}), {})
    assert isinstance(src, HatFileBattery)
    return src


def test_power_supply_directory(tmp_path: Path) -> None:
    ps = tmp_path / "BAT0"
    ps.mkdir()
    (ps / "voltage_now").write_text("7412000\n")  # uV, as the kernel writes it
    (ps / "capacity").write_text("63\n")
    r = _file_source(ps).read()
    assert r.voltage_v == pytest.approx(7.412) and r.percent == 63.0 and r.current_a is None
    (ps / "capacity").unlink()  # a driver without capacity: the voltage only, percent null ...
    assert _file_source(ps).read().percent is None
    # ... unless the pack's range is configured
    assert _file_source(ps, empty_v=6.4, full_v=8.4).read().percent == pytest.approx(50.6)


def test_uevent_json_and_single_number_files(tmp_path: Path) -> None:
    f = tmp_path / "battery"
    f.write_text("POWER_SUPPLY_NAME=ups\nPOWER_SUPPLY_VOLTAGE_NOW=4012000\nPOWER_SUPPLY_CAPACITY=88\n")
    r = _file_source(f).read()
    assert (r.voltage_v, r.percent) == (pytest.approx(4.012), 88.0)
    f.write_text('{"voltage_v": 3.95, "capacity": 71.5}')
    r = _file_source(f).read()
    assert (r.voltage_v, r.percent) == (3.95, 71.5)
    f.write_text("4.05\n")
    assert (_file_source(f).read().voltage_v, _file_source(f).read().percent) == (4.05, None)
    f.write_text("42\n")
    r = _file_source(f, value="percent").read()
    assert (r.voltage_v, r.percent) == (None, 42.0)
    f.write_text("3987000")
    assert _file_source(f, value="voltage_uv").read().voltage_v == pytest.approx(3.987)


@pytest.mark.parametrize(
    "text",
    [
        "",
        "garbage",
        "{not json",
        "[1, 2]",
        '{"voltage_v": "high"}',
        '{"capacity": 140}',
        "nan",
        "POWER_SUPPLY_CAPACITY=-5",
    ],
)
def test_unreadable_battery_file_gives_null_not_a_guess(tmp_path: Path, text: str) -> None:
    f = tmp_path / "battery"
    f.write_text(text)
    r = _file_source(f, empty_v=3.0, full_v=4.2).read()
    assert r.voltage_v is None and r.percent is None


def test_missing_battery_file_gives_null(tmp_path: Path) -> None:
    r = _file_source(tmp_path / "absent").read()
    assert (r.voltage_v, r.percent, r.current_a) == (None, None, None)
    assert parse_battery_text("") == (None, None)


# -- Wi-Fi ----------------------------------------------------------------------------------------------------
PROC_NET_WIRELESS = """\
Inter-| sta-|   Quality        |   Discarded packets               | Missed | WE
 face | tus | link level noise |  nwid  crypt   frag  retry   misc | beacon | 22
 wlan0: 0000   54.  -56.  -256        0      0      0      0      2        0
"""
# an old driver writing the level as an unsigned byte (dBm + 256), and a second interface
PROC_NET_WIRELESS_OLD = PROC_NET_WIRELESS + " wlan1: 0000   30.  195.  0     0      0      0      0      0        0\n"
IW_LINK = """\
Connected to 3c:84:6a:12:34:56 (on wlan0)
\tSSID: pool-lab
\tfreq: 5180
\tRX: 1843201 bytes (10233 packets)
\tTX: 402211 bytes (3110 packets)
\tsignal: -57 dBm
\trx bitrate: 390.0 MBit/s VHT-MCS 9 80MHz short GI VHT-NSS 1
\ttx bitrate: 433.3 MBit/s VHT-MCS 9 80MHz short GI VHT-NSS 1
\tbss flags:\tshort-slot-time
\tdtim period:\t1
\tbeacon int:\t100
"""


def test_proc_net_wireless_parsing() -> None:
    lines = parse_proc_net_wireless(PROC_NET_WIRELESS_OLD)
    assert [(w.interface, w.level_dbm) for w in lines] == [("wlan0", -56.0), ("wlan1", -61.0)]
    assert parse_proc_net_wireless(PROC_NET_WIRELESS.splitlines(keepends=True)[0]) == []


def test_iw_link_parsing() -> None:
    assert parse_iw_link(IW_LINK) == (-57.0, 433.3)
    assert parse_iw_link("Not connected.\n") == (None, None)
    assert parse_iw_link("") == (None, None)


def _fake_iw(tmp_path: Path, output: str) -> str:
    """An ``iw`` executable that prints recorded output for ``iw dev wlan0 link`` (a real process)."""
    recorded = tmp_path / "iw-output.txt"
    recorded.write_text(output)
    script = tmp_path / "iw"
    script.write_text(f'#!/bin/sh\n[ "$1 $2 $3" = "dev wlan0 link" ] || exit 1\ncat "{recorded}"\n')
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return str(script)


def test_wifi_reader_signal_from_proc_and_bitrate_from_iw(tmp_path: Path) -> None:
    proc = tmp_path / "wireless"
    proc.write_text(PROC_NET_WIRELESS)

    async def scenario() -> None:
        reader = WifiReader(proc_path=proc, iw_path=_fake_iw(tmp_path, IW_LINK))
        assert reader.read() == ("wlan0", -56.0, None)  # the bit rate is not known before iw answered
        await wait_until(lambda: reader.read()[2] is not None, 5, what="iw bit rate")
        assert reader.read() == ("wlan0", -56.0, 433.3)
        reader.close()

    asyncio.run(scenario())


def test_wifi_reader_without_wifi_gives_null(tmp_path: Path) -> None:
    async def scenario() -> None:
        # no /proc/net/wireless (a wired robot, a container) and no iw
        assert WifiReader(proc_path=tmp_path / "absent", iw_path=None).read() == (None, None, None)
        # a configured interface that is not in the file, with an iw that is not connected
        proc = tmp_path / "wireless"
        proc.write_text(PROC_NET_WIRELESS)
        reader = WifiReader("wlan0", proc_path=tmp_path / "absent", iw_path=_fake_iw(tmp_path, "Not connected.\n"))
        assert reader.read() == ("wlan0", None, None)
        task = reader._iw_task
        assert task is not None
        await task  # iw ran and answered "not connected": still null
        assert reader.read() == ("wlan0", None, None)
        reader.close()

    asyncio.run(scenario())


# -- CPU temperature -----------------------------------------------------------------------------------------
def test_cpu_temperature_from_thermal_zone(tmp_path: Path) -> None:
    zone = tmp_path / "temp"
    zone.write_text("48312\n")  # millidegrees
    assert read_cpu_temp_c(zone) == 48.31


# -- the schema ----------------------------------------------------------------------------------------------
def test_health_schema_is_validated_by_the_server_decoder() -> None:
    assert STREAM_SCHEMAS["health"] is HealthData
    ok = decode_telemetry(dumps({"ts": 1.0, "seq": 0, "data": {"battery_pct": 55.0, "cpu_temp_c": None}}), "health")
    assert ok.data["battery_pct"] == 55.0 and ok.data["wifi_rssi_dbm"] is None  # absent means null
    for bad in ({"battery_pct": 140}, {"battery_v": "full"}, {"motor_fault": "maybe"}, {"cpu_load": -1}):
        with pytest.raises(ProtocolError) as info:
            decode_telemetry(dumps({"ts": 1.0, "seq": 0, "data": bad}), "health")
        assert info.value.reason == "bad_health"
    with pytest.raises(ProtocolError):  # a JSON number too large for a float is not finite: refused
        decode_telemetry(b'{"ts": 1.0, "seq": 0, "data": {"cpu_temp_c": 1e999}}', "health")
    with pytest.raises(ValueError):
        HealthData(clock_offset_ms=math.nan)
