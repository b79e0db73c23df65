"""docker-compose.yml, .env.example and the Dockerfile, checked without a Docker engine (none here):
the compose file is valid for Compose v1 (`docker-compose config`), every variable is documented and
reaches a real server setting, and the commands the services run are run here for real, with the
environment compose gives them and without the vision extra (the image installs only `.[server]`)."""

from __future__ import annotations

import fnmatch
import json
import re
import secrets
import shlex
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml
from pydantic import AliasChoices

from backend.core.config import Settings
from tests.deploy.test_mosquitto import shipped_broker
from tests.support.procs import VENV_BIN, ManagedProcess, base_env, free_port, wait_for

ROOT = Path(__file__).resolve().parents[2]
PROFILES = ("sim", "postgres", "discovery")
#: variables only Compose itself uses (published ports, the postgres profile's password)
COMPOSE_ONLY_VARS = {"FLEET_HTTP_PORT", "FLEET_MQTT_PORT", "POSTGRES_PASSWORD", "FLEET_SIM_ROBOT_PASSWORD"}
ROBOTS = ("snail-1", "snail-2", "snail-3")
#: the Docker image has no vision extra: a service that imports these would crash in it
#: (runs ``main`` of a console script, given as "module:function", with these imports made to fail).
#: numpy is in the image: shapely, a base dependency (the geofence, the site, the missions), needs it.
NO_VISION = (
    "import importlib, sys\n"
    "for m in ('cv2', 'dt_apriltags'):\n"
    "    sys.modules[m] = None\n"
    "mod, fn = sys.argv[1].split(':')\n"
    "sys.argv = [sys.argv[1]] + sys.argv[2:]\n"
    "sys.exit(getattr(importlib.import_module(mod), fn)())\n"
)


def _compose_config(*extra: str) -> dict[str, Any]:
    exe = shutil.which("docker-compose")
    if exe is None:
        pytest.skip("docker-compose (Debian's Compose v1) is not installed: run scripts/ensure-system-deps.sh")
    args = [exe, "-f", str(ROOT / "docker-compose.yml"), *extra]
    for p in PROFILES:
        args += ["--profile", p]
    r = subprocess.run([*args, "config"], capture_output=True, text=True, cwd=ROOT, timeout=60, env=base_env())
    assert r.returncode == 0, r.stderr
    assert "WARNING" not in r.stderr, r.stderr
    config: dict[str, Any] = yaml.safe_load(r.stdout)
    return config


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    """The compose file as Compose resolves it with .env.example as its .env (what a new install has)."""
    return _compose_config("--env-file", str(ROOT / ".env.example"))


def _console_scripts() -> dict[str, str]:
    scripts: dict[str, str] = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    return scripts


def _as_in_image(command: list[str]) -> list[str]:
    """A service's command run here: the same console script and arguments, without the vision extra."""
    scripts = _console_scripts()
    assert command[0] in scripts, f"{command[0]} is not a console script of this package"
    return [sys.executable, "-c", NO_VISION, scripts[command[0]], *command[1:]]


def _settings_env_names() -> set[str]:
    names = set()
    for name, field in Settings.model_fields.items():
        names.add(f"FLEET_{name.upper()}")
        alias = field.validation_alias
        if isinstance(alias, AliasChoices):
            names |= {c for c in alias.choices if isinstance(c, str) and c.isupper()}
        elif isinstance(alias, str):
            names.add(alias)
    return names


def _dockerfile() -> list[tuple[str, str]]:
    """(instruction, arguments) of the Dockerfile, continuation lines joined."""
    text = re.sub(r"\\\n\s*", " ", (ROOT / "Dockerfile").read_text())
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            instr, _, rest = line.partition(" ")
            out.append((instr.upper(), rest.strip()))
    return out


def _healthcheck_command() -> list[str]:
    (args,) = [a for i, a in _dockerfile() if i == "HEALTHCHECK"]
    command: list[str] = json.loads(args.split(" CMD ", 1)[1])
    return command


# --------------------------------------------------------------------------------------------------


def test_services_profiles_volumes_and_restart_policies(compose: dict[str, Any]) -> None:
    services = compose["services"]
    assert set(services) == {
        "broker-init",
        "mosquitto",
        "server",
        "legacy-sentinel",
        "snail-1",
        "snail-2",
        "snail-3",
        "postgres",
        "discovery",
    }
    for name, svc in services.items():
        assert svc.get("restart") == ("no" if name == "broker-init" else "unless-stopped"), name
    # the base station proper runs without a profile; everything else is opt-in
    assert "profiles" not in services["mosquitto"] and "profiles" not in services["server"]
    for rid in ("snail-1", "snail-2", "snail-3"):
        assert services[rid]["profiles"] == ["sim"]
        assert "mosquitto" in services[rid]["depends_on"]
    assert services["postgres"]["profiles"] == ["postgres"]
    assert services["postgres"]["image"].startswith("postgres:16")
    assert services["discovery"]["profiles"] == ["discovery"] and services["discovery"]["network_mode"] == "host"

    mosq = services["mosquitto"]
    assert mosq["image"] == "eclipse-mosquitto:2"
    assert f"{ROOT / 'deploy' / 'mosquitto'}:/mosquitto/config:ro" in mosq["volumes"]
    assert "mosquitto-data:/mosquitto/data:rw" in mosq["volumes"]
    # authentication on: the broker starts only after broker-init wrote its passwd + acl into the volume it
    # reads them from, as the broker's own uid (the files are 0600)
    assert "mosquitto-auth:/mosquitto/auth:rw" in mosq["volumes"]
    assert mosq["depends_on"] == {"broker-init": {"condition": "service_completed_successfully"}}
    init = services["broker-init"]
    assert init["volumes"] == ["mosquitto-auth:/mosquitto/auth:rw"] and init["user"] == "1883:1883"
    assert "profiles" not in init
    assert {"published": 1883, "target": 1883} in mosq["ports"]

    server = services["server"]
    assert "mosquitto" in server["depends_on"]
    assert "fleet-data:/data:rw" in server["volumes"]
    assert {"published": 8000, "target": 8000} in server["ports"]
    assert server["environment"]["FLEET_MQTT_URL"] == "mqtt://mosquitto:1883"
    assert "FLEET_MQTT_PASSWORD" in server["environment"]
    assert init["environment"]["FLEET_MQTT_PASSWORD"] == server["environment"]["FLEET_MQTT_PASSWORD"]
    for rid in ROBOTS:
        assert services[rid]["environment"]["FLEET_AGENT_USERNAME"] == rid
        assert services[rid]["environment"]["FLEET_AGENT_PASSWORD"] == init["environment"]["FLEET_SIM_ROBOT_PASSWORD"]
    assert server["environment"]["FLEET_DATABASE_URL"] == "sqlite:////data/fleet.db"
    # the legacy sentinel runs beside the broker, with the server's account (tests/backend/services/
    # test_legacy_commands.py runs the same command against the shipped ACL)
    sentinel = services["legacy-sentinel"]
    assert sentinel["command"] == ["fleet-server", "legacy-sentinel"] and "profiles" not in sentinel
    assert sentinel["environment"]["FLEET_MQTT_PASSWORD"] == server["environment"]["FLEET_MQTT_PASSWORD"]
    # the robots, the server and the beacon all run the image this repository builds
    for name in ("broker-init", "server", "legacy-sentinel", "snail-1", "snail-2", "snail-3", "discovery"):
        assert services[name]["build"]["context"] == str(ROOT) and services[name]["image"] == "mollusca-fleet:latest"
    assert set(compose["volumes"]) == {"mosquitto-auth", "mosquitto-data", "fleet-data", "postgres-data"}


def test_the_file_also_resolves_without_an_env_file() -> None:
    """A clone with no .env yet: every variable has a default."""
    server = _compose_config()["services"]["server"]
    assert server["environment"]["FLEET_ENVIRONMENT"] == "production"
    assert server["environment"]["FLEET_AUTH"] == "on"


def test_every_variable_is_documented_and_reaches_a_real_setting(compose: dict[str, Any]) -> None:
    text = (ROOT / "docker-compose.yml").read_text()
    used = set(re.findall(r"\$\{([A-Z0-9_]+)", text))
    documented = set(re.findall(r"^([A-Z0-9_]+)=", (ROOT / ".env.example").read_text(), re.M))
    assert used == documented, (
        f"only in docker-compose.yml: {used - documented}; only in .env.example: {documented - used}"
    )
    settings = _settings_env_names()
    server_env = compose["services"]["server"]["environment"]
    assert set(server_env) <= settings, f"not server settings: {set(server_env) - settings}"
    assert documented - COMPOSE_ONLY_VARS <= settings
    for key, value in server_env.items():
        assert "#" not in str(value), f"{key}={value!r}: a comment leaked into the value"
    # the defaults a new install gets are accepted by the server's settings (apart from the two secrets)
    secret_env = {"FLEET_SECRET_KEY": secrets.token_urlsafe(48), "FLEET_ADMIN_TOKEN": secrets.token_urlsafe(48)}
    values = {k: str(v) for k, v in server_env.items()} | secret_env
    names = {f.upper(): f for f in Settings.model_fields}
    s = Settings.model_validate({names[k.removeprefix("FLEET_")].lower(): v for k, v in values.items()})
    assert s.environment == "production" and s.auth is True


def test_dockerfile_installs_the_tested_package_and_runs_unprivileged(compose: dict[str, Any]) -> None:
    instructions = _dockerfile()
    args_of: dict[str, list[str]] = {}
    for instr, args in instructions:
        args_of.setdefault(instr, []).append(args)
    assert args_of["FROM"] == ["python:3.11-slim"]
    assert any("pip install '.[server]'" in a for a in args_of["RUN"])
    assert args_of["USER"] == ["fleet"]
    assert args_of["WORKDIR"] == ["/app"]
    assert args_of["VOLUME"] == ['["/data"]']
    env = " ".join(args_of["ENV"])
    assert "FLEET_DATABASE_URL=sqlite:////data/fleet.db" in env and "FLEET_FRONTEND_DIR=/app/frontend" in env
    assert json.loads(args_of["CMD"][0]) == compose["services"]["server"]["command"]

    # everything the package needs is copied, and nothing copied is excluded by .dockerignore
    ignore = [
        ln.strip() for ln in (ROOT / ".dockerignore").read_text().splitlines() if ln.strip() and not ln.startswith("#")
    ]
    copied = [a.split()[:-1] for a in args_of["COPY"]]
    sources = [src for srcs in copied for src in srcs]
    for src in sources:
        assert (ROOT / src).exists(), src
        assert not any(fnmatch.fnmatch(src, pat) for pat in ignore), f"{src} is excluded by .dockerignore"
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    packages = [p.rstrip("*") for p in pyproject["tool"]["setuptools"]["packages"]["find"]["include"]]
    assert set(packages) <= set(sources)
    assert {"pyproject.toml", pyproject["project"]["readme"], "frontend"} <= set(sources)
    for secret in (".env", "deploy/mosquitto/passwd", ".git", ".venv"):
        assert secret in ignore


def _env(service: dict[str, Any], **override: str) -> dict[str, str]:
    return {k: str(v) for k, v in service.get("environment", {}).items()} | override


def _local_paths(command: list[str], auth_dir: Path) -> list[str]:
    """broker-init's container paths -> this test's: the auth volume and the ACL the image copies."""
    paths = {
        "/mosquitto/auth": str(auth_dir),
        "/app/deploy/mosquitto/acl.example": str(ROOT / "deploy" / "mosquitto" / "acl.example"),
    }
    return [paths.get(a, a) for a in command]


def test_compose_commands_run_for_real(compose: dict[str, Any], tmp_path: Path) -> None:
    """broker-init, then the shipped broker with what it wrote (authentication on), the server, and the
    three `sim` robots, each exactly as its service runs it with the environment compose resolves from an
    .env filled in as .env.example asks (only addresses, ports and paths are this test's)."""
    auth_dir = tmp_path / "auth"
    init_cmd = _local_paths(compose["services"]["broker-init"]["command"], auth_dir)

    # .env.example as shipped has no secrets: broker-init refuses (so the broker never starts) and the
    # production server refuses too, each saying which setting is missing
    r = subprocess.run(
        _as_in_image(init_cmd),
        env=base_env(**_env(compose["services"]["broker-init"])),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0 and "FLEET_MQTT_PASSWORD" in r.stderr, r.stderr + r.stdout
    assert not (auth_dir / "passwd").exists()

    filled = {
        "FLEET_SECRET_KEY": secrets.token_urlsafe(48),
        "FLEET_ADMIN_TOKEN": secrets.token_urlsafe(48),
        "FLEET_MQTT_PASSWORD": secrets.token_hex(24),
        "FLEET_SIM_ROBOT_PASSWORD": secrets.token_hex(24),
    }
    env_file = tmp_path / ".env"
    env_file.write_text(
        "".join(
            f"{k}={filled[k]}\n" if k in filled else line + "\n"
            for line in (ROOT / ".env.example").read_text().splitlines()
            for k in [line.partition("=")[0]]
        )
    )
    services = _compose_config("--env-file", str(env_file))["services"]
    assert services["server"]["environment"]["FLEET_MQTT_PASSWORD"] == filled["FLEET_MQTT_PASSWORD"]

    def broker_init() -> str:
        r = subprocess.run(
            _as_in_image(init_cmd),
            env=base_env(**_env(services["broker-init"])),
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert r.returncode == 0, r.stderr
        assert filled["FLEET_MQTT_PASSWORD"] not in r.stdout + r.stderr
        return r.stdout

    broker_init()
    first = (auth_dir / "passwd").read_bytes()
    out = broker_init()  # a second `up` keeps the files as they are (the hashes are salted)
    assert (auth_dir / "passwd").read_bytes() == first and "unchanged" in out
    assert sorted(line.split(":")[0] for line in first.decode().splitlines()) == ["fleet-server", *ROBOTS]
    for name in ("passwd", "acl"):
        assert oct((auth_dir / name).stat().st_mode & 0o777) == "0o600", name
    files = {name: (auth_dir / name).read_text() for name in ("passwd", "acl")}

    with shipped_broker("auth", files) as b:
        url = f"mqtt://127.0.0.1:{b.port}"
        port = free_port()
        server_cmd = [a if a != "8000" else str(port) for a in services["server"]["command"]]
        server_env = _env(
            services["server"], FLEET_MQTT_URL=url, FLEET_DATABASE_URL=f"sqlite:///{tmp_path / 'fleet.db'}"
        )
        procs = [ManagedProcess("server", _as_in_image(server_cmd), base_env(**server_env), tmp_path)]
        for rid in ROBOTS:
            cmd = [url if a == "mqtt://mosquitto:1883" else a for a in services[rid]["command"]]
            assert cmd != services[rid]["command"], "the robots connect to the compose broker"
            assert cmd[:3] == ["fleet-agent", "--robot-id", rid] and "--simulate" in cmd
            procs.append(ManagedProcess(rid, _as_in_image(cmd), base_env(**_env(services[rid])), tmp_path))
        base = f"http://127.0.0.1:{port}"
        token = filled["FLEET_ADMIN_TOKEN"]
        health = [sys.executable, *_healthcheck_command()[1:]]
        health[-1] = health[-1].replace("127.0.0.1:8000", f"127.0.0.1:{port}")
        try:
            for p in procs:
                p.start()

            def online() -> set[str]:
                try:
                    r = httpx.get(f"{base}/api/robots", headers={"Authorization": f"Bearer {token}"}, timeout=5)
                except httpx.TransportError:
                    return set()  # not listening yet
                assert r.status_code == 200, r.text
                return {x["id"] for x in r.json() if x["online"]}

            deadline = time.monotonic() + 60
            while online() < set(ROBOTS):  # fails at once when a service exits
                for p in procs:
                    assert p.alive(), f"{p.name} exited:\n{p.output()[-3000:]}"
                assert time.monotonic() < deadline, "the sim robots did not come online:\n" + "\n".join(
                    p.output()[-1500:] for p in procs
                )
                time.sleep(0.1)
            assert httpx.get(f"{base}/api/robots", timeout=5).status_code == 401  # FLEET_AUTH=on from compose
            for p in procs[1:]:
                assert p.alive(), p.output()[-3000:]

            # the image's HEALTHCHECK: healthy while database and broker are fine, unhealthy when not
            assert subprocess.run(health, capture_output=True, timeout=30).returncode == 0
            b.stop()
            wait_for(
                lambda: httpx.get(f"{base}/api/health", timeout=5).json()["status"] == "degraded",
                30,
                what="health degraded without the broker",
            )
            assert subprocess.run(health, capture_output=True, timeout=30).returncode == 1
        finally:
            for p in reversed(procs):
                p.stop()
        for p in procs:
            assert "Traceback" not in p.output(), p.output()[-3000:]
            for secret in filled.values():
                assert secret not in p.output(), f"{p.name} logged a secret"


def test_production_server_refuses_the_unfilled_env_example(compose: dict[str, Any], tmp_path: Path) -> None:
    server = compose["services"]["server"]
    cmd = [a if a != "8000" else str(free_port()) for a in server["command"]]
    env = _env(server, FLEET_DATABASE_URL=f"sqlite:///{tmp_path / 'fleet.db'}")
    r = subprocess.run(_as_in_image(cmd), env=base_env(**env), capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "FLEET_SECRET_KEY" in r.stderr, r.stderr


def test_beacon_command_is_a_real_cli_invocation(compose: dict[str, Any]) -> None:
    """The beacon broadcasts on the LAN, so it is only parsed here (`--help` after the same arguments)."""
    cmd = compose["services"]["discovery"]["command"]
    assert cmd[:2] == ["fleet-agent", "beacon"] and cmd[cmd.index("--broker-port") + 1] == "1883"
    # enrolled robots follow only a beacon that proves the server's fleet key, kept in its data volume
    assert cmd[cmd.index("--fleet-key-file") + 1] == "/data/fleet-key.secret"
    assert "fleet-data:/data:ro" in compose["services"]["discovery"]["volumes"]
    assert compose["services"]["server"]["environment"]["FLEET_DATA_DIR"] == "/data"
    r = subprocess.run([str(VENV_BIN / cmd[0]), *cmd[1:], "--help"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and "--broker-port" in r.stdout, r.stderr


def test_compose_robot_poses_are_inside_the_pool(compose: dict[str, Any]) -> None:
    for rid in ("snail-1", "snail-2", "snail-3"):
        cmd = compose["services"][rid]["command"]
        (pose,) = [a.split("=", 1)[1] for a in cmd if a.startswith("--start-pose=")]
        x, y, yaw = (float(v) for v in pose.split(","))
        assert abs(x) < 2 and abs(y) < 2 and -3.2 < yaw < 3.2, shlex.join(cmd)
