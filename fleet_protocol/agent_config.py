"""An agent's effective configuration, published retained on ``{prefix}/{id}/config`` so that a run can
record what every robot ran with (docs/protocol.md#agent-configuration).

Secrets never go on the wire: :func:`redact` replaces every value whose key names a secret (passwords,
tokens, keys) and strips credentials from URLs. The agent redacts before publishing; the server redacts
again what it receives (an older or foreign publisher may not have).
"""

from __future__ import annotations

import re
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from pydantic import Field, field_validator

from fleet_protocol.codec import _load_json, _validate
from fleet_protocol.core import _finite, _Wire

#: QoS of the config topic (retained: a server that starts later still learns it)
QOS_CONFIG = 1
#: what a redacted value reads as
REDACTED = "<redacted>"
#: parts of a key that name a secret anywhere in it, any case (``mqtt_password``, ``apiToken``...)
SECRET_WORDS = ("password", "passwd", "passphrase", "secret", "token", "credential", "apikey", "privatekey")
#: a key that is one of these words, or has one as a ``_``/``-``/``.``-separated part (``broker_pw``)
SECRET_PARTS = frozenset({"pass", "pw", "pwd", "key", "psk", "auth"})
_PART_SPLIT_RE = re.compile(r"[^a-z0-9]+")
_URL_WITH_USERINFO_RE = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://[^/@\s]*@")
#: nesting deeper than this is cut (a config is a few levels deep; this bounds the walk)
MAX_DEPTH = 12


def is_secret_key(key: str) -> bool:
    low = key.lower()
    squashed = _PART_SPLIT_RE.sub("", low)
    if any(word in squashed for word in SECRET_WORDS):
        return True
    return any(part in SECRET_PARTS for part in _PART_SPLIT_RE.split(low))


def strip_url_credentials(value: str) -> str:
    """``mqtt://user:pw@host:1883`` -> ``mqtt://host:1883``; any other string unchanged."""
    if not _URL_WITH_USERINFO_RE.match(value):
        return value
    try:
        parts = urlsplit(value)
    except ValueError:
        return REDACTED
    host = parts.hostname or ""
    if ":" in host:  # IPv6 literal
        host = f"[{host}]"
    try:
        port = parts.port
    except ValueError:
        port = None
    netloc = host if port is None else f"{host}:{port}"
    return urlunsplit((parts.scheme, netloc, parts.path, parts.query, parts.fragment))


def redact(value: Any, depth: int = 0) -> Any:
    """A copy of a JSON-like value with secrets removed: values under secret-named keys become
    :data:`REDACTED` (``null`` stays ``null``: "not set" is not a secret), URLs lose their credentials."""
    if depth > MAX_DEPTH:
        return REDACTED
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for k, v in value.items():
            key = str(k)
            if is_secret_key(key) and v is not None and not isinstance(v, bool):
                out[key] = REDACTED
            else:
                out[key] = redact(v, depth + 1)
        return out
    if isinstance(value, list | tuple):
        return [redact(v, depth + 1) for v in value]
    if isinstance(value, str):
        return strip_url_credentials(value)
    return value


class AgentConfig(_Wire):
    """``{prefix}/{id}/config``, retained: what the agent runs with, secrets removed."""

    ts: float
    agent_version: str = Field(default="", max_length=64)
    protocol_version: int | None = Field(default=None, ge=0)
    #: the agent's boot id (as in its telemetry): a new one after every agent start
    boot: str = Field(default="", max_length=64)
    #: the effective settings (file, environment and flags merged, defaults filled in), redacted
    config: dict[str, Any] = Field(default_factory=dict)

    _ts = field_validator("ts")(_finite)

    @field_validator("config")
    @classmethod
    def _redacted(cls, v: dict[str, Any]) -> dict[str, Any]:
        return redact(v)


def decode_agent_config(payload: bytes) -> AgentConfig | None:
    """None for an empty payload (a retained config being cleared)."""
    if not payload:
        return None
    return _validate(AgentConfig, _load_json(payload), "bad_config")
