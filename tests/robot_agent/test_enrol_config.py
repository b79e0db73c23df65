"""`fleet-agent enrol` writes the enrolment into the agent's config without breaking it (issue 29 #3): the
shipped template keeps every other line and stays valid, a second enrolment replaces the first, and what the
enrolment does not name (no broker: discovery) stays as the file has it."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from robot_agent.config import load_settings
from robot_agent.enrol import EnrolError, Enrolment, apply, updated_config

EXAMPLE = Path(__file__).resolve().parents[2] / "robot_agent" / "deploy" / "agent.example.toml"
KEY = "ab" * 32


def _enrolment(**changes: object) -> Enrolment:
    values: dict[str, object] = {
        "robot_id": "snail-9",
        "username": "snail-9",
        "password": "pw-0123456789abcdef",
        "broker": None,
        "fleet_key": KEY,
        "tls_ca": None,
    }
    return Enrolment.model_validate(values | changes)


def test_the_template_takes_an_enrolment_and_stays_valid(tmp_path: Path) -> None:
    config = tmp_path / "agent.toml"
    config.write_text(EXAMPLE.read_text())
    apply(_enrolment(), config)
    settings = load_settings({"config": str(config)}, environ={})
    assert settings.robot_id == "snail-9" and settings.username == "snail-9"
    assert settings.broker is None  # not named: discovery, pinned by the key
    assert settings.discovery_pins().fleet_key == bytes.fromhex(KEY)
    assert oct(config.stat().st_mode & 0o777) == "0o600"
    before, after = EXAMPLE.read_text().splitlines(), config.read_text().splitlines()
    assert [ln for ln in before if not ln.startswith("robot_id = ")] == [
        ln
        for ln in after
        if ln.split(" = ")[0] not in ("robot_id", "username", "password", "fleet_key")
        and not ln.startswith("# set by `fleet-agent enrol`")
    ]
    # enrolled again, with a broker and a CA: one block, the newer values, the CA next to the config
    pem = "-----BEGIN CERTIFICATE-----\nMIIB\n-----END CERTIFICATE-----\n"
    apply(_enrolment(password="pw-second-0123456789", broker="mqtts://base.lab:8883", tls_ca=pem), config)
    text = config.read_text()
    assert text.count("# set by `fleet-agent enrol`") == 1 and text.count("\nrobot_id = ") == 1
    data = tomllib.loads(text)
    assert data["password"] == "pw-second-0123456789" and data["broker"] == "mqtts://base.lab:8883"
    assert Path(data["tls_ca"]).read_text() == pem


def test_a_config_it_cannot_update_is_refused_not_broken() -> None:
    with pytest.raises(EnrolError, match="by hand"):
        updated_config('password = """two\nlines"""\n', {"password": "x" * 12})
    with pytest.raises(ValueError):
        _enrolment(fleet_key="not-a-key")
