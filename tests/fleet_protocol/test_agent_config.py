"""An agent's published configuration: secrets are removed wherever they sit, the rest is kept as is; the
topic is parsed under the prefix; a bad payload is a ProtocolError, an empty one a clear."""

from __future__ import annotations

import orjson
import pytest

from fleet_protocol import REDACTED, AgentConfig, ProtocolError, Topics, decode_agent_config, redact


def test_secrets_are_redacted_at_any_depth_and_urls_lose_their_credentials() -> None:
    cfg = {
        "robot_id": "snail-1",
        "username": "snail-1",
        "password": "hunter2",
        "broker": "mqtt://snail-1:hunter2@base:1883",
        "tls_ca": None,
        "sensors": [
            {"type": "position", "rate_hz": 20.0, "api_token": "abc"},
            {"type": "camera", "url": "rtsp://cam:pw@10.0.0.5/stream", "Secret-Key": "k"},
        ],
        "motors": {"type": "gpio", "pins": [1, 2], "pw": "x", "auth_key": "y", "keepalive": 5},
        "discovery": {"mdns": True, "private_key": None},
        "bypass_check": 3,
    }
    out = redact(cfg)
    assert out["password"] == REDACTED and out["username"] == "snail-1"
    assert out["broker"] == "mqtt://base:1883"
    assert out["sensors"][0] == {"type": "position", "rate_hz": 20.0, "api_token": REDACTED}
    assert out["sensors"][1]["url"] == "rtsp://10.0.0.5/stream" and out["sensors"][1]["Secret-Key"] == REDACTED
    assert out["motors"] == {"type": "gpio", "pins": [1, 2], "pw": REDACTED, "auth_key": REDACTED, "keepalive": 5}
    assert out["discovery"] == {"mdns": True, "private_key": None}  # not set is not a secret
    assert out["bypass_check"] == 3 and out["tls_ca"] is None
    assert "hunter2" not in orjson.dumps(out).decode()
    assert cfg["password"] == "hunter2"  # a copy: the agent's own settings are untouched


def test_the_payload_model_redacts_what_it_is_given() -> None:
    """The server decodes with the same model: a publisher that forgot to redact is redacted on arrival."""
    raw = orjson.dumps({"ts": 1.5, "agent_version": "0.1", "config": {"password": "p", "broker": "mqtt://u:p@h"}})
    msg = decode_agent_config(raw)
    assert isinstance(msg, AgentConfig)
    assert msg.config == {"password": REDACTED, "broker": "mqtt://h"}
    assert decode_agent_config(b"") is None  # a retained config being cleared
    for bad in (b"[]", b"{", b'{"ts": "x"}', b'{"ts": 1, "config": []}'):
        with pytest.raises(ProtocolError):
            decode_agent_config(bad)


def test_config_topic_is_built_and_parsed_under_the_prefix() -> None:
    t = Topics("lab/pool")
    assert t.config("snail-1") == "lab/pool/snail-1/config"
    assert t.all_configs() == "lab/pool/+/config"
    parsed = t.parse("lab/pool/snail-1/config")
    assert parsed.kind.value == "config" and parsed.robot_id == "snail-1"
