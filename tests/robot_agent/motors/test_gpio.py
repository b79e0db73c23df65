"""GPIO motor driver on gpiozero's mock pins (the only mocked part: the hardware)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

gpiozero = pytest.importorskip("gpiozero")
from gpiozero.pins.mock import MockFactory, MockPWMPin  # noqa: E402

from robot_agent.motors import create_motor_driver, validate_motor_config  # noqa: E402
from robot_agent.motors.base import MotorConfigError  # noqa: E402
from robot_agent.motors.gpio import GpioMotorConfig, GpioMotorDriver  # noqa: E402

PINS = {"left_forward": 17, "left_backward": 18, "right_forward": 22, "right_backward": 23}


@pytest.fixture
def factory() -> Iterator[MockFactory]:
    f = MockFactory(pin_class=MockPWMPin)
    gpiozero.Device.pin_factory = f
    try:
        yield f
    finally:
        f.reset()
        gpiozero.Device.pin_factory = None


def pin(f: MockFactory, n: int) -> Any:
    return f.pin(n)


def driver(**kw: Any) -> GpioMotorDriver:
    d = create_motor_driver({"type": "gpio", **PINS, **kw}, None)
    assert isinstance(d, GpioMotorDriver)
    return d


def test_forward_backward_turn_and_stop_drive_the_right_pins(factory: MockFactory) -> None:
    d = driver()
    try:
        d.set(0.6, 0.6)
        assert pin(factory, 17).state == pytest.approx(0.6) and pin(factory, 18).state == 0
        assert pin(factory, 22).state == pytest.approx(0.6) and pin(factory, 23).state == 0
        d.set(-0.4, 0.3)  # turning left
        assert pin(factory, 17).state == 0 and pin(factory, 18).state == pytest.approx(0.4)
        assert pin(factory, 22).state == pytest.approx(0.3) and pin(factory, 23).state == 0
        d.set(2.0, -2.0)  # clamped
        assert pin(factory, 17).state == 1 and pin(factory, 23).state == 1
        d.stop()
        assert all(pin(factory, n).state == 0 for n in PINS.values())
        assert d.operable() == (True, "")
    finally:
        d.close()


def test_pwm_frequency_comes_from_config(factory: MockFactory) -> None:
    d = driver(pwm_frequency=250)
    try:
        d.set(0.5, -0.5)
        assert pin(factory, 17).frequency == 250
        assert pin(factory, 23).frequency == 250
    finally:
        d.close()


def test_enable_pins_are_driven_high(factory: MockFactory) -> None:
    d = driver(left_enable=5, right_enable=6)
    try:
        assert pin(factory, 5).state == 1 and pin(factory, 6).state == 1
    finally:
        d.close()


def test_inverted_motor(factory: MockFactory) -> None:
    d = driver(invert_right=True)
    try:
        d.set(0.5, 0.5)
        assert pin(factory, 17).state == pytest.approx(0.5)
        assert pin(factory, 22).state == 0 and pin(factory, 23).state == pytest.approx(0.5)
    finally:
        d.close()


def test_fault_line_makes_motors_not_operable(factory: MockFactory) -> None:
    d = driver(fault_pin=26)  # active low, pulled up
    try:
        assert d.operable() == (True, "")
        pin(factory, 26).drive_low()
        ok, why = d.operable()
        assert not ok and "fault" in why and "26" in why
        pin(factory, 26).drive_high()
        assert d.operable()[0]
    finally:
        d.close()


def test_closed_driver_is_not_operable_and_releases_pins(factory: MockFactory) -> None:
    d = driver()
    d.set(0.5, 0.5)
    d.close()
    assert d.operable() == (False, "motor driver closed")
    assert all(pin(factory, n).state == 0 for n in PINS.values())
    again = driver()  # pins are free again
    again.close()


def test_pin_conflict_fails_cleanly(factory: MockFactory) -> None:
    with pytest.raises(Exception, match=r"17|in use"):
        driver(right_forward=17)
    d = driver()  # nothing leaked from the failed attempt
    d.close()


def test_config_is_validated_with_extra_forbidden() -> None:
    with pytest.raises(MotorConfigError, match="pwm"):
        validate_motor_config({"type": "gpio", **PINS, "pwm": 100})
    with pytest.raises(MotorConfigError, match="unknown motor type"):
        validate_motor_config({"type": "steam"})
    cfg = validate_motor_config({"type": "gpio", **PINS})
    assert isinstance(cfg, GpioMotorConfig) and cfg.pwm_frequency == 1000


def test_gpiozero_is_imported_lazily() -> None:
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import robot_agent.motors, robot_agent.agent, robot_agent.cli, robot_agent.link.discovery\n"
        "bad = [m for m in ('gpiozero', 'zeroconf', 'numpy', 'cv2') if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_motor_fault_for_the_health_stream(factory: MockFactory) -> None:
    blind = driver()  # no fault pin: the driver cannot tell, so the health stream says null
    try:
        assert blind.motor_fault is None
    finally:
        blind.close()
    d = driver(fault_pin=26)
    try:
        assert d.motor_fault is False
        pin(factory, 26).drive_low()  # active low: the driver reports a fault
        assert d.motor_fault is True
        pin(factory, 26).drive_high()
        assert d.motor_fault is False
    finally:
        d.close()
