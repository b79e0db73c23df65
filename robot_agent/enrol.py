"""``fleet-agent enrol SERVER TOKEN``: exchange a one-time enrolment token for this robot's broker account and
the pin of its base station, and write them into the agent's config (issue 29 #3).

``fleet-server robots add ID`` on the base station prints the line (``install-pi.sh --enrol`` runs this): the
token is single-use and expires, so nothing a shell history or ``ps`` keeps can be used again, and the
password and the fleet key go straight from the server's answer into the config file (mode 0600), never
through a command line or a screen.
"""

from __future__ import annotations

import argparse
import json
import os
import ssl
import sys
import tempfile
import tomllib
import urllib.error
import urllib.request
from collections.abc import Sequence
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from fleet_protocol import ROBOT_ID_PATTERN
from fleet_protocol.discovery import parse_fleet_key
from robot_agent.config import parse_broker_url

CA_FILE = "fleet-ca.crt"


class Enrolment(BaseModel):
    """The server's answer (``POST /api/enrol``), checked before anything is written."""

    model_config = ConfigDict(extra="ignore")

    robot_id: str = Field(pattern=ROBOT_ID_PATTERN)
    username: str = Field(min_length=1, max_length=256)
    password: str = Field(min_length=8, max_length=256)
    broker: str | None = Field(default=None, max_length=500)
    fleet_key: str
    tls_ca: str | None = Field(default=None, max_length=65536)

    @field_validator("broker")
    @classmethod
    def _check_broker(cls, v: str | None) -> str | None:
        if v:
            parse_broker_url(v)
        return v or None

    @field_validator("fleet_key")
    @classmethod
    def _check_key(cls, v: str) -> str:
        parse_fleet_key(v)
        return v

    @field_validator("tls_ca")
    @classmethod
    def _check_ca(cls, v: str | None) -> str | None:
        if v and "-----BEGIN CERTIFICATE-----" not in v:
            raise ValueError("tls_ca is not a PEM certificate")
        return v or None


class EnrolError(Exception):
    """The exchange or the config update failed; the message says why (never a secret)."""


def redeem(server: str, token: str, cafile: str | None = None, timeout: float = 30.0) -> Enrolment:
    """``POST {server}/api/enrol {"token": ...}``: the answer, or EnrolError with the server's reason."""
    url = server.rstrip("/") + "/api/enrol"
    if not url.startswith(("http://", "https://")):
        raise EnrolError(f"the server's URL must start with http:// or https://, not {server!r}")
    request = urllib.request.Request(
        url,
        data=json.dumps({"token": token}).encode(),
        headers={"Content-Type": "application/json", "Accept": "application/json"},
        method="POST",
    )
    context = ssl.create_default_context(cafile=cafile) if url.startswith("https://") else None
    try:
        with urllib.request.urlopen(request, timeout=timeout, context=context) as response:
            body = response.read(1 << 20)
    except urllib.error.HTTPError as exc:
        try:
            detail = json.loads(exc.read(4096))
            why = f"{detail.get('detail')} ({detail.get('code')})"
        except (ValueError, AttributeError):
            why = exc.reason
        raise EnrolError(f"{url}: {exc.code}: {why}") from None
    except (urllib.error.URLError, OSError) as exc:
        raise EnrolError(f"cannot reach {url}: {getattr(exc, 'reason', exc)}") from None
    try:
        return Enrolment.model_validate_json(body)
    except ValidationError as exc:
        fields = ", ".join(".".join(map(str, e["loc"])) for e in exc.errors(include_input=False))
        raise EnrolError(f"{url} answered something that is not an enrolment (bad {fields})") from None


def _toml_string(value: str) -> str:
    """A TOML basic string: JSON's escapes are TOML's (``\\"``, ``\\\\``, ``\\n``, ``\\uXXXX``)."""
    return json.dumps(value, ensure_ascii=True)


MARKER = "# set by `fleet-agent enrol` (the broker account and the base station's pin; keep this file 0600)"


def updated_config(text: str, values: dict[str, str]) -> str:
    """``text`` with the top-level ``values`` set, every other line kept.

    The enrolled keys' old top-level lines are dropped and the new ones go where the settings start (after
    the file's opening comments); the result is parsed again, so a file this cannot update is refused, not
    broken."""
    lines = text.splitlines()
    first_table = next((i for i, ln in enumerate(lines) if ln.lstrip().startswith("[")), len(lines))
    head, tables = lines[:first_table], lines[first_table:]
    kept = [
        ln for ln in head if ln != MARKER and (ln.lstrip().startswith("#") or ln.split("=", 1)[0].strip() not in values)
    ]
    start = next((i for i, ln in enumerate(kept) if ln.strip() and not ln.lstrip().startswith("#")), len(kept))
    block = [MARKER, *(f"{key} = {_toml_string(value)}" for key, value in values.items())]
    out = "\n".join([*kept[:start], *block, *kept[start:], *tables]) + "\n"
    try:
        parsed = tomllib.loads(out)
    except tomllib.TOMLDecodeError as exc:
        raise EnrolError(f"cannot update the config ({exc}): set {', '.join(values)} by hand") from None
    for key, value in values.items():
        if parsed.get(key) != value:
            raise EnrolError(f"cannot update the config: {key} is set in a way this cannot change; edit it by hand")
    return out


def _write_private(path: Path, text: str, mode: int = 0o600) -> None:
    """Written whole under a temporary name, then renamed over ``path``: never half a config."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}-", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def apply(enrolment: Enrolment, config: Path) -> None:
    """Write the enrolment into ``config`` (created if missing) and the CA next to it. What the enrolment
    does not name (no broker: discovery; no CA) stays as the file has it."""
    config.parent.mkdir(parents=True, exist_ok=True)
    text = config.read_text() if config.exists() else ""
    values = {
        "robot_id": enrolment.robot_id,
        "username": enrolment.username,
        "password": enrolment.password,
        "fleet_key": enrolment.fleet_key,
    }
    if enrolment.broker:
        values["broker"] = enrolment.broker
    if enrolment.tls_ca:
        ca = config.parent / CA_FILE
        _write_private(ca, enrolment.tls_ca, mode=0o644)  # a CA certificate is public
        values["tls_ca"] = str(ca)
    _write_private(config, updated_config(text, values))


def main_enrol(argv: Sequence[str]) -> int:
    p = argparse.ArgumentParser(
        prog="fleet-agent enrol",
        description="Exchange a one-time enrolment token (from `fleet-server robots add ID`) for this robot's "
        "broker account and the base station's pin, and write them into the agent's config.",
    )
    p.add_argument("server", help="the fleet server, e.g. http://base.lab:8000")
    p.add_argument("token", help="the enrolment token (single use, expires)")
    p.add_argument("--config", type=Path, default=Path("/etc/fleet-agent/agent.toml"), help="the agent's config")
    p.add_argument("--cacert", default=None, help="CA certificate of an https:// server (default: the system's)")
    args = p.parse_args(list(argv))
    try:
        enrolment = redeem(args.server, args.token, args.cacert)
        apply(enrolment, args.config)
    except (EnrolError, OSError) as exc:
        print(f"fleet-agent enrol: {exc}", file=sys.stderr)
        return 1
    how = f"broker {enrolment.broker}" if enrolment.broker else "the broker found by discovery, pinned by the fleet key"
    ca = f" and {args.config.parent / CA_FILE}" if enrolment.tls_ca else ""
    print(f"enrolled as robot {enrolment.robot_id} ({how}): wrote {args.config}{ca}")
    return 0
