"""The health sensor in process: its sample validates against HealthData, the simulated battery drains
with the sim motors' set-points (and only a little when idle), the motor fault and clock offset come from
the agent's own objects, and what is not configured is null."""

from __future__ import annotations

import asyncio
import time
from typing import Any

import pytest

from fleet_protocol import PROTOCOL_VERSION, AvoidanceSettings, FleetPoses, HealthData, dumps
from robot_agent import __version__
from robot_agent.link.clock_sync import ClockSync
from robot_agent.motion.collision_guard import GuardedMotors
from robot_agent.motion.kinematics import Kinematics
from robot_agent.motion.neighbours import NeighbourTable
from robot_agent.motors.sim import SimMotorDriver
from robot_agent.sensors import SENSOR_REGISTRY
from robot_agent.sensors.base import SensorContext
from robot_agent.sensors.battery.ina219 import Ina219Battery
from robot_agent.sensors.health import HealthConfig, HealthPlugin
from robot_agent.sensors.supervisor import SensorConfigError, build_plugins
from robot_agent.sim.world import SimWorld
from tests.support.procs import wait_for


def _plugin(config: dict[str, Any], shared: dict[str, Any]) -> HealthPlugin:
    ctx = SensorContext(
        robot_id="h1",
        emit=lambda s, d: None,
        emit_retained=lambda s, d: None,
        emit_camera=lambda s, p: None,
        world=None,
        shared=shared,
    )
    [plugin] = build_plugins([{"type": "health", **config}], SENSOR_REGISTRY, lambda: ctx)
    assert isinstance(plugin, HealthPlugin)
    return plugin


def test_sample_without_a_battery_source_or_sync_has_null_fields_and_versions() -> None:
    motors = SimMotorDriver(SimWorld())
    plugin = _plugin({}, {"motors": motors, "clock": ClockSync(lambda b: None)})
    data = HealthData.model_validate(plugin.sample()).model_dump()
    assert data["battery_v"] is None and data["battery_pct"] is None and data["battery_a"] is None
    assert data["clock_offset_ms"] is None  # not synced yet: unknown, not 0
    assert data["agent_version"] == __version__ and data["protocol_version"] == PROTOCOL_VERSION
    assert data["motor_fault"] is False and data["motor_fault_reason"] is None  # the sim driver knows
    assert data["mem_used_pct"] is not None and data["disk_free_mb"] is not None  # psutil measures these
    assert data["uptime_s"] is not None and data["uptime_s"] >= 0
    assert plugin.stream == "health" and plugin.config.rate_hz == 1.0


def test_no_motor_driver_means_motor_fault_unknown() -> None:
    assert _plugin({}, {}).sample()["motor_fault"] is None


def test_hears_poses_follows_the_safety_filter() -> None:
    """False until the fleet's poses come (the server's readiness reads it), null once a site turns the filter
    off."""
    kin = Kinematics(wheel_base_m=0.2, max_wheel_speed_mps=0.3, max_linear_mps=0.2, max_angular_rps=1.5)
    guard = GuardedMotors(
        SimMotorDriver(SimWorld()), kinematics=kin, neighbours=NeighbourTable("me"), emit=lambda s, d: None
    )
    plugin = _plugin({}, {"collision_guard": guard})
    assert plugin.sample()["hears_poses"] is False  # just started: no site and no poses yet
    guard.configure(AvoidanceSettings(), 0.3)
    assert plugin.sample()["hears_poses"] is False
    guard.on_poses_payload(dumps(FleetPoses(server_id="s", ts=time.time(), seq=0, robots=[])))
    assert plugin.sample()["hears_poses"] is True
    guard.configure(None, 0.3)  # a site without avoidance (an older server): the filter is off
    assert plugin.sample()["hears_poses"] is None
    assert _plugin({}, {}).sample()["hears_poses"] is None


def test_simulated_motor_fault_is_reported_with_its_reason() -> None:
    plugin = _plugin({}, {"motors": SimMotorDriver(SimWorld(), fault="overcurrent")})
    sample = plugin.sample()
    assert sample["motor_fault"] is True and sample["motor_fault_reason"] == "simulated fault: overcurrent"


def test_simulated_battery_drains_with_driving_not_standing() -> None:
    motors = SimMotorDriver(SimWorld())
    plugin = _plugin(
        {"battery": {"type": "sim", "start_pct": 80, "drain_pct_per_s": 10, "idle_drain_pct_per_h": 0}},
        {"motors": motors},
    )
    asyncio.run(plugin.start())
    first = plugin.sample()
    assert first["battery_pct"] == 80.0
    assert first["battery_v"] == pytest.approx(6.4 + 2.0 * 0.8)
    # standing still for a measurable time: no drain (the idle rate is 0 here) ...
    t0 = time.monotonic()
    wait_for(lambda: time.monotonic() - t0 > 0.2, what="time standing still")
    assert plugin.sample()["battery_pct"] == 80.0
    # ... driving at half speed on both wheels drains 10 %/s x 0.5 x the time driven
    motors.set(0.5, -0.5)
    driven_from = time.monotonic()
    wait_for(lambda: time.monotonic() - driven_from > 0.3, what="time driving")
    motors.stop()
    driven_s = time.monotonic() - driven_from
    drained = 80.0 - plugin.sample()["battery_pct"]
    assert drained == pytest.approx(10 * 0.5 * driven_s, abs=0.05)
    assert drained > 1.0
    # stopped: the charge holds
    after = plugin.sample()["battery_pct"]
    wait_for(lambda: time.monotonic() - driven_from > driven_s + 0.2, what="time stopped")
    assert plugin.sample()["battery_pct"] == after


def test_sim_battery_refuses_to_run_without_the_sim_motors() -> None:
    plugin = _plugin({"battery": {"type": "sim"}}, {})
    with pytest.raises(RuntimeError, match="sim motor driver"):
        asyncio.run(plugin.start())


def test_bad_battery_config_is_a_sensor_config_error() -> None:
    with pytest.raises(SensorConfigError, match="unknown battery type"):
        _plugin({"battery": {"type": "nuclear"}}, {})
    with pytest.raises(SensorConfigError, match="shunt_ohms"):
        _plugin({"battery": {"type": "ina219", "shunt_ohms": 0}}, {})


def test_a_failing_battery_read_gives_null_battery_and_the_rest_still_publishes() -> None:
    class BrokenBus:
        def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
            raise OSError(121, "Remote I/O error")

        def close(self) -> None:
            pass

    cfg = HealthConfig.model_validate({"type": "health", "battery": {"type": "ina219"}})
    ctx = SensorContext(
        robot_id="h1", emit=lambda s, d: None, emit_retained=lambda s, d: None, emit_camera=lambda s, p: None
    )
    battery = Ina219Battery(cfg.battery, {}, bus=BrokenBus())
    sample = HealthPlugin(cfg, ctx, battery=battery).sample()
    assert sample["battery_v"] is None and sample["battery_pct"] is None
    assert sample["mem_used_pct"] is not None


def test_simulated_robots_get_health_by_default_with_the_start_level() -> None:
    from robot_agent.config import ConfigError, default_sensor_configs, load_settings

    sim = load_settings({"robot_id": "h1", "simulate": True, "battery_start_pct": 42.5}, environ={})
    health = [c for c in default_sensor_configs(sim) if c["type"] == "health"]
    assert health == [{"type": "health", "battery": {"type": "sim", "start_pct": 42.5}}]
    off = load_settings({"robot_id": "h1", "simulate": True, "health": False}, environ={})
    assert all(c["type"] != "health" for c in default_sensor_configs(off))
    robot = load_settings({"robot_id": "h1"}, environ={})  # hardware: configured in agent.toml instead
    assert all(c["type"] != "health" for c in default_sensor_configs(robot))
    with pytest.raises(ConfigError, match="battery_start_pct"):
        load_settings({"robot_id": "h1", "simulate": True, "battery_start_pct": 120}, environ={})


def test_wifi_sample_outside_a_loop_does_not_start_iw(tmp_path: Any) -> None:
    from robot_agent.sensors.wifi import WifiReader

    proc = tmp_path / "wireless"
    proc.write_text("h1\nh2\n wlan0: 0000   54.  -56.  -256  0 0 0 0 2 0\n")
    reader = WifiReader(proc_path=proc, iw_path="/bin/true")  # an iw exists, but there is no loop to run it
    assert reader.read() == ("wlan0", -56.0, None)
    assert reader._iw_task is None
