"""Settings precedence: CLI > FLEET_AGENT_* env > TOML file > defaults."""

from __future__ import annotations

from pathlib import Path

import pytest

from robot_agent.cli import main
from robot_agent.config import ConfigError, load_settings, parse_broker_url, parse_start_pose

TOML = """
robot_id = "from-file"
broker = "mqtt://10.0.0.1:1883"
keepalive = 30
position_rate = 5
buffer_size = 77
extra_commands = ["set_speed"]

[motors]
type = "sim"

[[sensors]]
type = "position"
rate_hz = 7

[legacy_udp]
imu_port = 15005
"""


def test_file_values_apply(tmp_path: Path) -> None:
    f = tmp_path / "agent.toml"
    f.write_text(TOML)
    s = load_settings({"config": str(f)}, environ={})
    assert s.robot_id == "from-file" and s.keepalive == 30 and s.buffer_size == 77
    assert s.broker_address() == ("10.0.0.1", 1883)
    assert s.sensors == [{"type": "position", "rate_hz": 7}]
    assert s.motors == {"type": "sim"}
    assert s.legacy_udp.imu_port == 15005 and s.legacy_udp.position_port == 5006
    assert s.extra_commands == ["set_speed"]


def test_env_beats_file_and_cli_beats_env(tmp_path: Path) -> None:
    f = tmp_path / "agent.toml"
    f.write_text(TOML)
    env = {
        "FLEET_AGENT_CONFIG": str(f),
        "FLEET_AGENT_KEEPALIVE": "12",
        "FLEET_AGENT_ROBOT_ID": "from-env",
        "FLEET_AGENT_BROKER": "mqtt://env-host:1999",
    }
    s = load_settings({}, environ=env)
    assert (s.robot_id, s.keepalive, s.broker, s.buffer_size) == ("from-env", 12, "mqtt://env-host:1999", 77)
    s = load_settings({"robot_id": "from-cli", "keepalive": 3}, environ=env)
    assert (s.robot_id, s.keepalive, s.broker) == ("from-cli", 3, "mqtt://env-host:1999")


def test_defaults() -> None:
    s = load_settings({"robot_id": "r1"}, environ={})
    assert s.broker is None and s.prefix == "fleet" and s.keepalive == 5 and s.position_rate == 20
    assert s.simulate is False and s.max_speed_mps == 0.3 and s.sensors == []
    assert s.legacy_udp.position_port == 5006 and s.discovery.udp_port == 7000 and s.discovery.ack_port == 7002


def test_env_reads_the_process_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FLEET_AGENT_ROBOT_ID", "envbot")
    monkeypatch.setenv("FLEET_AGENT_SIMULATE", "true")
    s = load_settings({})
    assert s.robot_id == "envbot" and s.simulate is True


@pytest.mark.parametrize(
    "cli",
    [
        {"robot_id": "bad id!"},
        {"robot_id": "r", "broker": "http://x"},
        {"robot_id": "r", "keepalive": 0},
        {"robot_id": "r", "start_pose": "1,2,x"},
        {"robot_id": "r", "bogus": 1},
        {},
    ],
)
def test_invalid_settings_raise_config_error(cli: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        load_settings(cli, environ={})


def test_unknown_key_in_file_is_refused(tmp_path: Path) -> None:
    f = tmp_path / "a.toml"
    f.write_text('robot_id = "r"\nspeeed = 3\n')
    with pytest.raises(ConfigError, match="speeed"):
        load_settings({"config": str(f)}, environ={})
    f.write_text("robot_id = ")
    with pytest.raises(ConfigError, match="cannot read"):
        load_settings({"config": str(f)}, environ={})
    with pytest.raises(ConfigError, match="not found"):
        load_settings({"config": str(tmp_path / "missing.toml")}, environ={})


def test_broker_url_and_pose_parsing() -> None:
    assert parse_broker_url("mqtt://h:1884") == ("h", 1884)
    assert parse_broker_url("h") == ("h", 1883)
    assert parse_broker_url("tcp://1.2.3.4") == ("1.2.3.4", 1883)
    with pytest.raises(ValueError):
        parse_broker_url("mqtt://h:notaport")
    assert parse_start_pose("1, -2, 0.5") == (1.0, -2.0, 0.5)
    assert parse_start_pose("1,2") == (1.0, 2.0, 0.0)
    with pytest.raises(ValueError):
        parse_start_pose("nan,1,2")


def test_cli_exits_2_on_bad_settings(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("FLEET_AGENT_ROBOT_ID", raising=False)
    assert main(["--robot-id", "no spaces allowed", "--broker", "mqtt://127.0.0.1:1"]) == 2
    assert "invalid settings" in capsys.readouterr().err


def test_cli_rejects_bad_sensor_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "a.toml"
    f.write_text('[[sensors]]\ntype = "imu"\nrate_hz = 5\nwrong_field = 1\n')
    assert main(["--robot-id", "r", "--broker", "mqtt://127.0.0.1:1", "--simulate", "--config", str(f)]) == 2
    assert "wrong_field" in capsys.readouterr().err
    f.write_text('[[sensors]]\ntype = "sonar"\n')
    assert main(["--robot-id", "r", "--broker", "mqtt://127.0.0.1:1", "--simulate", "--config", str(f)]) == 2
    assert "unknown sensor type 'sonar'" in capsys.readouterr().err
