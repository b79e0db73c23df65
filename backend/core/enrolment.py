"""Enrolment tokens (issue 29 #3): ``fleet-server robots add ID`` makes one, the robot exchanges it once at
``POST /api/enrol`` for its broker password and the base station's pin.

The token is ``fle_`` + 256 random bits. The database keeps only ``sha256(token)`` to find the row, and the
robot's password sealed with a key only the token yields (a SHAKE-256 stream over the token, used for this
one password only), so a copy of the database opens no pending enrolment.
"""

from __future__ import annotations

import hashlib
import re
import secrets

TOKEN_PREFIX = "fle_"
TOKEN_PATTERN = r"^fle_[A-Za-z0-9_-]{43}$"
#: the longest a token may stay usable (``robots add --enrol-ttl``, default 30 minutes)
MAX_TTL_S = 24 * 3600
_SEAL_CONTEXT = b"mollusca-fleet enrolment seal 1\n"
_TOKEN = re.compile(TOKEN_PATTERN)


def new_token() -> str:
    return TOKEN_PREFIX + secrets.token_urlsafe(32)


def is_token(text: str) -> bool:
    return bool(_TOKEN.match(text))


def token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def _pad(token: str, length: int) -> bytes:
    return hashlib.shake_256(_SEAL_CONTEXT + token.encode()).digest(length)


def seal(token: str, password: str) -> str:
    data = password.encode()
    return bytes(a ^ b for a, b in zip(data, _pad(token, len(data)), strict=True)).hex()


def unseal(token: str, sealed: str) -> str:
    data = bytes.fromhex(sealed)
    return bytes(a ^ b for a, b in zip(data, _pad(token, len(data)), strict=True)).decode()
