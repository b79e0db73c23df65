"""Agent settings: CLI flags over ``FLEET_AGENT_*`` environment variables over a TOML file over defaults.

The TOML file (``--config`` / ``FLEET_AGENT_CONFIG``) uses the same names as the flags at top level, plus
the ``[motors]`` table, the ``[[sensors]]`` plugin list and the ``[legacy_udp]`` / ``[discovery]`` tables
(see ``robot_agent/deploy/agent.example.toml``).
"""

from __future__ import annotations

import ipaddress
import math
import os
import tomllib
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from pydantic import BaseModel, ConfigDict, Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, InitSettingsSource, PydanticBaseSettingsSource, SettingsConfigDict

from fleet_protocol import DEFAULT_PREFIX, ROBOT_ID_PATTERN
from fleet_protocol.discovery import parse_fleet_key
from robot_agent.link.pins import Pins
from robot_agent.motion.kinematics import KinematicsConfig
from robot_agent.sim.disturbances import SimDisturbances


class ConfigError(ValueError):
    """Settings that cannot work (bad file, bad value); the CLI exits with status 2."""


class LegacyUdpConfig(BaseModel):
    """UDP inputs of today's Mollusca sensor modules (the seed's ports)."""

    model_config = ConfigDict(extra="forbid")

    bind: str = "127.0.0.1"
    imu_port: int = Field(default=5005, ge=0, le=65535)
    position_port: int = Field(default=5006, ge=0, le=65535)
    apriltag_port: int = Field(default=5007, ge=0, le=65535)


class DiscoveryConfig(BaseModel):
    """How to find the broker when none is configured."""

    model_config = ConfigDict(extra="forbid")

    mdns: bool = True
    udp: bool = True
    udp_port: int = Field(default=7000, ge=1, le=65535)
    ack_port: int = Field(default=7002, ge=1, le=65535)
    #: Give up after this long (0 = keep trying forever, as a robot at boot should).
    timeout_s: float = Field(default=0.0, ge=0.0)
    #: Broker port assumed when the UDP broadcast only carries an IP address.
    default_port: int = Field(default=1883, ge=1, le=65535)
    #: Interface addresses to browse mDNS on; empty = all interfaces.
    mdns_interfaces: list[str] = Field(default_factory=list, max_length=32)
    #: Address the UDP broadcast listener binds to; "" = all addresses.
    udp_bind: str = ""

    @field_validator("mdns_interfaces")
    @classmethod
    def _check_interfaces(cls, v: list[str]) -> list[str]:
        for addr in v:
            ipaddress.ip_address(addr)  # ValueError names the bad address
        return v

    @field_validator("udp_bind")
    @classmethod
    def _check_bind(cls, v: str) -> str:
        if v:
            ipaddress.ip_address(v)
        return v


class AgentSettings(BaseSettings):
    """Everything the agent needs; see the module docstring for precedence."""

    model_config = SettingsConfigDict(env_prefix="FLEET_AGENT_", extra="forbid", populate_by_name=True)

    robot_id: str = Field(pattern=ROBOT_ID_PATTERN)
    #: ``mqtt://host:port`` (``mqtts://`` for TLS); None = discover (mDNS and the seed's UDP broadcast,
    #: whichever answers first).
    broker: str | None = None
    #: Broker credentials (``fleet-server robots add ID`` prints them); None = anonymous. With only a
    #: password the username is the robot id (the shipped ACL's convention).
    username: str | None = Field(default=None, min_length=1, max_length=256)
    password: SecretStr | None = None
    #: CA certificate that signed the broker's TLS certificate (``mqtts://``); None = the system's CAs.
    #: Also a pin for discovery: with it (and no fleet key) only ``mqtts://`` answers are followed.
    tls_ca: Path | None = None
    #: The fleet key (64 hex digits, from enrolment): discovery follows only a beacon that proves it holds
    #: it too (fleet_protocol/discovery.py). A robot with a password and no pin does not discover at all.
    fleet_key: SecretStr | None = None
    simulate: bool = False
    #: With no ``[[sensors]]`` configured: also run the camera stream and AprilTag detection (sim: a
    #: rendered camera; hardware: Picamera2 or the first OpenCV camera).
    camera: bool = False
    prefix: str = DEFAULT_PREFIX
    config: Path | None = None
    keepalive: int = Field(default=5, ge=1, le=3600)
    position_rate: float = Field(default=20.0, gt=0.0, le=1000.0)
    imu_rate: float = Field(default=10.0, gt=0.0, le=1000.0)
    #: ``X,Y,YAW`` (metres, radians) for the simulated robot; default derived from the robot id.
    start_pose: str | None = None
    max_speed_mps: float = Field(default=0.3, gt=0.0, le=10.0)
    wheel_base_m: float = Field(default=0.2, gt=0.0, le=5.0)
    #: With no ``[[sensors]]`` and simulate: the health stream (1 Hz) and its simulated battery's start charge.
    health: bool = True
    battery_start_pct: float = Field(default=100.0, ge=0.0, le=100.0)
    #: Telemetry messages kept while the broker is unreachable (drop-oldest beyond this).
    buffer_size: int = Field(default=1000, ge=1, le=1_000_000)
    #: Gap repair: every stream's telemetry of the last ``replay_window_s`` (at most ``replay_max_bytes`` in
    #: all) is kept so the server can ask for what the broker dropped; ``replay_dir`` also keeps it on disk,
    #: so that it survives an agent restart (None: memory only).
    replay_window_s: float = Field(default=600.0, gt=0.0, le=86400.0)
    replay_max_bytes: int = Field(default=50_000_000, ge=0, le=10_000_000_000)
    replay_dir: Path | None = None
    reconnect_min_s: float = Field(default=0.5, gt=0.0, le=60.0)
    reconnect_max_s: float = Field(default=10.0, gt=0.0, le=600.0)
    #: A failed sensor is retried after 0.5 s, doubling up to this (seconds).
    sensor_retry_max_s: float = Field(default=30.0, ge=0.5, le=3600.0)
    log_level: str = "INFO"
    #: Extra command handlers to enable beyond the seed's set (e.g. ``["set_speed"]``).
    extra_commands: list[str] = Field(default_factory=list)
    motors: dict[str, Any] = Field(default_factory=dict)
    #: ``[[sensors]]`` plugin configs; empty = defaults (sim: position + imu; hardware: legacy UDP inputs).
    sensors: list[dict[str, Any]] = Field(default_factory=list)
    legacy_udp: LegacyUdpConfig = Field(default_factory=LegacyUdpConfig)
    discovery: DiscoveryConfig = Field(default_factory=DiscoveryConfig)
    #: ``[kinematics]``: wheel base, wheel and body speed limits (robot_agent/motion/kinematics.py).
    kinematics: KinematicsConfig = Field(default_factory=KinematicsConfig)
    #: ``[sim]``: the simulator's disturbances (robot_agent/sim/disturbances.py; docs/autonomy.md).
    sim: SimDisturbances = Field(default_factory=SimDisturbances)
    #: ``--disturbances`` / ``--no-current``: override ``sim.disturbances`` / ``sim.current``.
    disturbances: bool | None = None
    current: bool | None = None

    @field_validator("broker")
    @classmethod
    def _check_broker(cls, v: str | None) -> str | None:
        if v is None or v == "":
            return None
        parse_broker_url(v)
        return v

    @field_validator("password")
    @classmethod
    def _empty_password_is_none(cls, v: SecretStr | None) -> SecretStr | None:
        return v if v is not None and v.get_secret_value() else None

    @field_validator("fleet_key")
    @classmethod
    def _check_fleet_key(cls, v: SecretStr | None) -> SecretStr | None:
        if v is None or not v.get_secret_value().strip():
            return None
        parse_fleet_key(v.get_secret_value())  # ValueError says what a key looks like, never the value
        return v

    @model_validator(mode="after")
    def _sim_switches(self) -> AgentSettings:
        if self.disturbances is not None:
            self.sim.disturbances = self.disturbances
        if self.current is not None:
            self.sim.current = self.current
        return self

    @model_validator(mode="after")
    def _check_credentials(self) -> AgentSettings:
        if self.password is not None and self.username is None:
            self.username = self.robot_id  # the ACL's convention: a robot's broker account is its id
        return self

    @field_validator("start_pose")
    @classmethod
    def _check_pose(cls, v: str | None) -> str | None:
        if v:
            parse_start_pose(v)
        return v or None

    @field_validator("log_level")
    @classmethod
    def _check_level(cls, v: str) -> str:
        v = v.upper()
        if v not in ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"):
            raise ValueError("log_level must be DEBUG, INFO, WARNING, ERROR or CRITICAL")
        return v

    def discovery_pins(self) -> Pins:
        """What a discovered broker must show before this agent sends it its password."""
        key = self.fleet_key.get_secret_value() if self.fleet_key is not None else None
        return Pins(fleet_key=parse_fleet_key(key) if key else None, tls_only=self.tls_ca is not None)

    def broker_address(self) -> tuple[str, int]:
        if self.broker is None:
            raise ConfigError("no broker configured")
        return parse_broker_url(self.broker)

    def start_pose_tuple(self) -> tuple[float, float, float] | None:
        return parse_start_pose(self.start_pose) if self.start_pose else None


def default_sensor_configs(settings: AgentSettings) -> list[dict[str, Any]]:
    """Sensors when the config lists none: the simulated ones, or today's UDP-fed modules on a robot."""
    source = "sim" if settings.simulate else "legacy"
    configs: list[dict[str, Any]] = [
        {"type": "position", "source": source, "rate_hz": settings.position_rate},
        {"type": "imu", "source": source, "rate_hz": settings.imu_rate},
    ]
    if settings.camera:
        configs += [{"type": "camera"}, {"type": "apriltag"}]
    if settings.simulate and settings.health:
        configs.append({"type": "health", "battery": {"type": "sim", "start_pct": settings.battery_start_pct}})
    return configs


def sensor_configs(settings: AgentSettings) -> list[dict[str, Any]]:
    """The ``[[sensors]]`` entries to build: the configured ones (or the defaults), flags applied."""
    raw = [dict(c) for c in settings.sensors] or default_sensor_configs(settings)
    for c in raw:  # --position-rate applies to a configured position sensor that sets no rate itself
        if c.get("type") == "position":
            c.setdefault("rate_hz", settings.position_rate)
    return raw


def parse_broker_url(url: str, default_port: int = 1883) -> tuple[str, int]:
    """``mqtt://host[:port]``, ``mqtts://host[:port]`` (TLS, default port 8883) or ``host[:port]``."""
    if "://" not in url:
        url = "mqtt://" + url
    parts = urlsplit(url)
    if parts.scheme not in ("mqtt", "tcp", "mqtts", "ssl"):
        raise ValueError(f"unsupported broker scheme {parts.scheme!r} (use mqtt://host:port or mqtts://)")
    if parts.username or parts.password:
        raise ValueError("put broker credentials in username/password, not in the broker URL")
    if parts.scheme in ("mqtts", "ssl") and default_port == 1883:
        default_port = 8883
    if not parts.hostname:
        raise ValueError(f"broker URL {url!r} has no host")
    try:
        port = parts.port or default_port
    except ValueError:
        raise ValueError(f"broker URL {url!r} has a bad port") from None
    return parts.hostname, port


def parse_start_pose(text: str) -> tuple[float, float, float]:
    parts = [p.strip() for p in text.split(",")]
    if len(parts) not in (2, 3):
        raise ValueError(f"start pose must be X,Y[,YAW], got {text!r}")
    vals = [float(p) for p in parts] + ([0.0] if len(parts) == 2 else [])
    if not all(math.isfinite(v) for v in vals):
        raise ValueError("start pose must be finite numbers")
    return vals[0], vals[1], vals[2]


def read_toml(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"config file {path} not found") from None
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"cannot read config file {path}: {exc}") from None


def load_settings(cli: dict[str, Any] | None = None, environ: dict[str, str] | None = None) -> AgentSettings:
    """Build the settings: ``cli`` values (None = not given) > environment > TOML file > defaults."""
    cli = {k: v for k, v in (cli or {}).items() if v is not None}
    env = os.environ if environ is None else environ
    path_value = cli.get("config") or env.get("FLEET_AGENT_CONFIG")
    file_data: dict[str, Any] = read_toml(Path(path_value)) if path_value else {}
    file_data.pop("config", None)

    class _Settings(AgentSettings):
        @classmethod
        def settings_customise_sources(
            cls,
            settings_cls: type[BaseSettings],
            init_settings: PydanticBaseSettingsSource,
            env_settings: PydanticBaseSettingsSource,
            dotenv_settings: PydanticBaseSettingsSource,
            file_secret_settings: PydanticBaseSettingsSource,
        ) -> tuple[PydanticBaseSettingsSource, ...]:
            from pydantic_settings import EnvSettingsSource

            env_source: PydanticBaseSettingsSource = env_settings
            if environ is not None:
                env_source = EnvSettingsSource(settings_cls, env_prefix="FLEET_AGENT_")
                env_source.env_vars = {k.lower(): v for k, v in environ.items()}
            return (init_settings, env_source, InitSettingsSource(settings_cls, init_kwargs=file_data))

    from pydantic import ValidationError

    try:
        return _Settings(**cli)
    except ValidationError as exc:
        raise ConfigError(str(exc)) from None
