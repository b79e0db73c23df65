"""The files a lab installs on a robot: the config template loads and validates with the agent's own
loaders (every section, every plugin), documents every setting the agent knows (each optional line, once
uncommented, is valid too), the install script is valid bash, the unit restarts on failure."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from robot_agent.config import AgentSettings, DiscoveryConfig, LegacyUdpConfig, load_settings
from robot_agent.motion.kinematics import KinematicsConfig
from robot_agent.motors import MOTOR_REGISTRY, validate_motor_config
from robot_agent.sensors import SENSOR_REGISTRY
from robot_agent.sensors.base import SensorContext
from robot_agent.sensors.battery import BATTERY_REGISTRY
from robot_agent.sensors.supervisor import build_plugins
from robot_agent.sim.disturbances import SimDisturbances

DEPLOY = Path(__file__).resolve().parents[2] / "robot_agent" / "deploy"
EXAMPLE = DEPLOY / "agent.example.toml"
#: an optional setting: "# key = value" (prose comments never start like that)
OPTIONAL = re.compile(r"^# (\w+) = ")
COMMENTED_BLOCK = re.compile(r"^# \[\[sensors\]\]")


def _ctx() -> SensorContext:
    return SensorContext(
        robot_id="snail-1",
        emit=lambda s, d: None,
        emit_retained=lambda s, d: None,
        emit_camera=lambda s, p: None,
        world=None,
        shared={},
    )


def _validate(path: Path) -> tuple[AgentSettings, list[Any]]:
    """Everything the agent validates at start, without opening any device."""
    settings = load_settings({"config": str(path)}, environ={})
    validate_motor_config(dict(settings.motors), "none")
    plugins = build_plugins(settings.sensors, SENSOR_REGISTRY, _ctx)
    return settings, plugins


def test_example_config_is_valid_for_every_section() -> None:
    settings, plugins = _validate(EXAMPLE)
    assert settings.robot_id == "snail-1" and settings.broker is None  # discovery by default
    assert validate_motor_config(dict(settings.motors), "none").type == "gpio"  # type: ignore[attr-defined]
    assert [p.type_name for p in plugins] == ["position", "imu", "camera", "apriltag", "health"]
    assert settings.discovery.udp_port == 7000 and settings.legacy_udp.position_port == 5006


def _optional_groups(lines: list[str]) -> list[list[int]]:
    """Line numbers to uncomment together: one optional setting, or a whole commented [[sensors]] block."""
    groups: list[list[int]] = []
    i = 0
    while i < len(lines):
        if COMMENTED_BLOCK.match(lines[i]):
            j = i + 1
            while j < len(lines) and OPTIONAL.match(lines[j]):
                j += 1
            groups.append(list(range(i, j)))
            i = j
        elif OPTIONAL.match(lines[i]):
            groups.append([i])
            i += 1
        else:
            i += 1
    return groups


def test_every_optional_line_is_valid_when_uncommented(tmp_path: Path) -> None:
    lines = EXAMPLE.read_text().splitlines()
    groups = _optional_groups(lines)
    assert len(groups) > 25
    for group in groups:
        variant = list(lines)
        for n in group:
            variant[n] = variant[n][2:]
        path = tmp_path / "variant.toml"
        path.write_text("\n".join(variant) + "\n")
        try:
            _validate(path)
        except Exception as exc:  # name the line in the failure
            pytest.fail(f"agent.example.toml line {group[0] + 1} ({lines[group[0]]!r}) is invalid: {exc}")


def _documented_keys(text: str) -> set[str]:
    keys = set()
    for line in text.splitlines():
        if m := re.match(r"^(?:# )?(\w+) = ", line):
            keys.add(m.group(1))
        if m := re.match(r"^(?:# )?\[\[?(?:\w+\.)?(\w+)\]\]?", line):  # [motors], [sensors.battery]
            keys.add(m.group(1))
    return keys


def _fields(model: type[BaseModel]) -> set[str]:
    return set(model.model_fields)


def test_every_setting_is_documented() -> None:
    text = EXAMPLE.read_text()
    keys = _documented_keys(text)
    wanted = (_fields(AgentSettings) - {"config"}) | _fields(LegacyUdpConfig) | _fields(DiscoveryConfig)
    wanted |= _fields(MOTOR_REGISTRY["gpio"][0]) | _fields(KinematicsConfig) | _fields(SimDisturbances)
    for cls in SENSOR_REGISTRY.values():
        wanted |= _fields(cls.config_model)
    # the health sensor's [sensors.battery]: the ina219 keys as lines, the other sources' in its prose
    wanted |= _fields(BATTERY_REGISTRY["ina219"].config_model)
    for kind in ("file", "sim"):
        prose = _fields(BATTERY_REGISTRY[kind].config_model) - {"type"}
        assert all(f" {k}" in text for k in prose), f"battery {kind} options not all documented"
    # settings of the plugins every [[sensors]] block shares, documented once in prose
    shared = {"stream", "rate_hz", "enabled"}
    assert all(f"{k} = " in text for k in shared)
    # the sim motor's options are explained in the [motors] prose (they cannot sit next to type = "gpio")
    assert _fields(MOTOR_REGISTRY["sim"][0]) == {"type", "fault", "trace_file"}
    assert "its options: fault names" in text and "trace_file a file" in text
    missing = sorted(wanted - keys - {"fault", "trace_file"})
    assert not missing, f"settings not in agent.example.toml: {missing}"
    unknown = sorted(keys - wanted - shared)
    assert not unknown, f"agent.example.toml documents settings the agent does not know: {unknown}"


def test_install_script_and_unit() -> None:
    r = subprocess.run(["bash", "-n", str(DEPLOY / "install-pi.sh")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    script = (DEPLOY / "install-pi.sh").read_text()
    assert "--system-site-packages" in script and "python3-picamera2" in script and "[vision,pi]" in script
    assert "python3-venv" in script and "systemctl enable" in script
    # idempotent: the venv, the user and the config are only created when missing
    assert 'if [ ! -x "$PREFIX/.venv/bin/python" ]' in script and 'if [ ! -f "$CONF_DIR/agent.toml" ]' in script
    unit = (DEPLOY / "fleet-agent.service").read_text()
    assert "Restart=on-failure" in unit and "WantedBy=multi-user.target" in unit
    assert "After=network-online.target" in unit
    exec_line = next(line for line in unit.splitlines() if line.startswith("ExecStart="))
    assert exec_line == "ExecStart=/opt/fleet-agent/.venv/bin/fleet-agent --config /etc/fleet-agent/agent.toml"


def test_install_script_writes_the_robot_id_into_a_valid_config(tmp_path: Path) -> None:
    """The sed line install-pi.sh uses to make the config from the template, run for real."""
    script = (DEPLOY / "install-pi.sh").read_text()
    (sed_line,) = [ln.strip() for ln in script.splitlines() if ln.strip().startswith("sed ")]
    env = {"PATH": "/usr/bin:/bin", "REPO": str(DEPLOY.parents[1]), "CONF_DIR": str(tmp_path), "ROBOT_ID": "snail-42"}
    subprocess.run(["bash", "-c", sed_line], check=True, env=env)
    settings, _ = _validate(tmp_path / "agent.toml")
    assert settings.robot_id == "snail-42"
