"""Broker discovery's proof of the base station (issue 29 #3): a challenge and its signed answer.

The old broadcast (the broker's IP on UDP 7000) can come from anyone on the network, and a robot that
followed it would send its broker password to whoever answered first. A robot holding the **fleet key** (32
random bytes the base station keeps and enrolment hands out) follows only an answer that proves the sender
holds it too: on hearing a broadcast, or finding an mDNS record, it sends :func:`challenge` (16 fresh random
bytes) to that host's ACK port; the beacon answers :func:`proof`: the broker URL and
``HMAC-SHA256(fleet key, nonce + URL)``. A recorded answer is worthless (every challenge is new), no clock
is involved (a Pi at boot may not know the time yet), and a rogue that passes the challenge on to the real
beacon gets back the real broker's URL, which is the one the robot then uses.

Datagrams (ASCII, one line, fields separated by one space)::

    MFLEET-CHALLENGE-1 <nonce: 32 hex>
    MFLEET-PROOF-1 <nonce: 32 hex> <broker URL> <HMAC: 64 hex>
"""

from __future__ import annotations

import hashlib
import hmac
import re

#: bytes of the fleet key; its text form (key file, agent config, enrolment answer) is 64 hex digits
FLEET_KEY_BYTES = 32
NONCE_BYTES = 16
CHALLENGE_PREFIX = b"MFLEET-CHALLENGE-1 "
PROOF_PREFIX = b"MFLEET-PROOF-1 "
#: what the MAC covers besides nonce and URL: a proof can never pass for anything else signed with the key
_PROOF_CONTEXT = b"mollusca-fleet beacon proof 1\n"
_HEX_KEY = re.compile(r"^[0-9a-f]{64}$")
#: a broker URL in a proof: mqtt:// or mqtts://, a host (name, IPv4 or [IPv6]) and a port
_PROOF_URL = re.compile(r"^mqtts?://[A-Za-z0-9.\-\[\]:]{1,255}:[0-9]{1,5}$")


def parse_fleet_key(text: str) -> bytes:
    """The key from its text form (64 hex digits, surrounding white space ignored); ValueError otherwise."""
    value = text.strip().lower()
    if not _HEX_KEY.match(value):
        raise ValueError(f"a fleet key is {FLEET_KEY_BYTES * 2} hex digits")
    return bytes.fromhex(value)


def challenge(nonce: bytes) -> bytes:
    if len(nonce) != NONCE_BYTES:
        raise ValueError(f"a nonce is {NONCE_BYTES} bytes")
    return CHALLENGE_PREFIX + nonce.hex().encode()


def parse_challenge(data: bytes) -> bytes | None:
    """The nonce of a challenge datagram, None for anything else."""
    if not data.startswith(CHALLENGE_PREFIX):
        return None
    text = data[len(CHALLENGE_PREFIX) :].strip()
    if len(text) != NONCE_BYTES * 2:
        return None
    try:
        return bytes.fromhex(text.decode("ascii"))
    except (UnicodeDecodeError, ValueError):
        return None


def _mac(key: bytes, nonce: bytes, url: str) -> str:
    return hmac.new(key, _PROOF_CONTEXT + nonce + b"\n" + url.encode("ascii"), hashlib.sha256).hexdigest()


def proof(key: bytes, nonce: bytes, url: str) -> bytes:
    """The beacon's answer to a challenge: the broker URL, signed together with the nonce."""
    if not _PROOF_URL.match(url):
        raise ValueError(f"not a broker URL for a proof: {url!r}")
    return PROOF_PREFIX + f"{nonce.hex()} {url} {_mac(key, nonce, url)}".encode("ascii")


def proof_nonce(data: bytes) -> bytes | None:
    """The nonce a proof datagram answers (unverified: look up the challenge, then :func:`verify_proof`)."""
    if not data.startswith(PROOF_PREFIX):
        return None
    first = data[len(PROOF_PREFIX) :].split(b" ", 1)[0]
    if len(first) != NONCE_BYTES * 2:
        return None
    try:
        return bytes.fromhex(first.decode("ascii"))
    except (UnicodeDecodeError, ValueError):
        return None


def verify_proof(key: bytes, nonce: bytes, data: bytes) -> str | None:
    """The broker URL of a proof that answers ``nonce`` and carries a valid MAC; None for anything else."""
    if not data.startswith(PROOF_PREFIX):
        return None
    try:
        fields = data[len(PROOF_PREFIX) :].decode("ascii").strip().split(" ")
    except UnicodeDecodeError:
        return None
    if len(fields) != 3:
        return None
    nonce_hex, url, mac = fields
    if not _PROOF_URL.match(url) or not hmac.compare_digest(nonce_hex, nonce.hex()):
        return None
    if not hmac.compare_digest(mac, _mac(key, nonce, url)):
        return None
    return url
