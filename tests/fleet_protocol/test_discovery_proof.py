"""The signed beacon's wire format (fleet_protocol/discovery.py, issue 29 #3): a proof verifies only with the
key, for the nonce it answers and the URL it carries; anything else is refused, never mistaken for a proof."""

from __future__ import annotations

import secrets

import pytest

from fleet_protocol.discovery import (
    challenge,
    parse_challenge,
    parse_fleet_key,
    proof,
    proof_nonce,
    verify_proof,
)

KEY = bytes(range(32))


def test_a_proof_verifies_only_with_its_key_nonce_and_url() -> None:
    nonce = secrets.token_bytes(16)
    assert parse_challenge(challenge(nonce)) == nonce
    signed = proof(KEY, nonce, "mqtt://192.168.1.10:1883")
    assert proof_nonce(signed) == nonce
    assert verify_proof(KEY, nonce, signed) == "mqtt://192.168.1.10:1883"
    assert verify_proof(bytes(32), nonce, signed) is None  # another key
    assert verify_proof(KEY, secrets.token_bytes(16), signed) is None  # a replay for a new challenge
    forged = signed.replace(b"192.168.1.10", b"192.168.1.66")
    assert verify_proof(KEY, nonce, forged) is None  # the URL is signed too
    tls = proof(KEY, nonce, "mqtts://base.lab:8883")
    assert verify_proof(KEY, nonce, tls) == "mqtts://base.lab:8883"


@pytest.mark.parametrize(
    "data",
    [b"", b"ACK", b"192.168.1.10", b"MFLEET-PROOF-1 zz", b"MFLEET-PROOF-1 " + b"a" * 500, b"MFLEET-CHALLENGE-1 00"],
)
def test_anything_else_is_no_proof(data: bytes) -> None:
    assert verify_proof(KEY, bytes(16), data) is None
    assert parse_challenge(data) is None


def test_fleet_key_text() -> None:
    assert parse_fleet_key(KEY.hex().upper() + "\n") == KEY
    for bad in ("", "00" * 31, "zz" * 32, "00" * 33):
        with pytest.raises(ValueError, match="64 hex digits"):
            parse_fleet_key(bad)
    with pytest.raises(ValueError):
        proof(KEY, bytes(16), "http://evil.example/")
