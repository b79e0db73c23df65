"""What a robot checks before it follows a discovered broker (issue 29 #3): its pins, and the challenges it
sends to beacons (the wire format is fleet_protocol/discovery.py). Used by robot_agent/link/discovery.py."""

from __future__ import annotations

import contextlib
import secrets
import socket
import time
from dataclasses import dataclass

from fleet_protocol.discovery import challenge, proof_nonce, verify_proof

#: a pinned robot challenges one sender at most this often ...
CHALLENGE_INTERVAL_S = 1.0
#: ... and takes its answer for this long
PROOF_TIMEOUT_S = 3.0
_MAX_PENDING = 64


@dataclass(frozen=True)
class Pins:
    """What a discovered broker must show before the robot connects to it (and sends its password)."""

    #: follow only a beacon that proves it holds this key
    fleet_key: bytes | None = None
    #: without a key: follow only ``mqtts://`` answers (the agent verifies them against its ``tls_ca``)
    tls_only: bool = False

    def accepts_unproven(self, url: str) -> bool:
        return self.fleet_key is None and (not self.tls_only or url.startswith("mqtts://"))

    def describe(self) -> str:
        if self.fleet_key is not None:
            return "fleet key"
        return "mqtts:// with tls_ca only" if self.tls_only else "none"


def refusal(has_password: bool, pins: Pins) -> str | None:
    """Why this agent must not discover (None: it may): a password and nothing to recognise the base
    station by would go to whoever answers first."""
    if not has_password or pins.fleet_key is not None or pins.tls_only:
        return None
    return (
        "discovery refused: this robot has a broker password but no way to recognise its base station (no "
        "fleet_key, no tls_ca), so the first answer on the network would get the password. Enrol the robot "
        "(on the base station `fleet-server robots add ID` prints the command for the Pi; docs/security.md, "
        '"Discovery and enrolment") or set `broker`.'
    )


class Challenges:
    """A pinned robot's outstanding challenges: every sender of a broadcast is challenged (at most once per
    :data:`CHALLENGE_INTERVAL_S`), and only a proof of one of these nonces, within :data:`PROOF_TIMEOUT_S`
    and signed with the key, is taken."""

    def __init__(self, key: bytes) -> None:
        self.key = key
        self._pending: dict[bytes, float] = {}
        self._last: dict[str, float] = {}

    def due(self, sender: str, now: float) -> bytes | None:
        """A new challenge datagram for ``sender``, or None when it was challenged a moment ago."""
        last = self._last.get(sender)
        if last is not None and now - last < CHALLENGE_INTERVAL_S:
            return None
        self._prune(now)
        if len(self._pending) >= _MAX_PENDING:
            return None  # a flood of senders: the ones asked already answer first
        nonce = secrets.token_bytes(16)
        self._pending[nonce] = now
        self._last[sender] = now
        return challenge(nonce)

    def answer(self, data: bytes, now: float) -> str | None:
        """The broker URL of a valid proof of an outstanding challenge (which is then used up)."""
        nonce = proof_nonce(data)
        sent = self._pending.get(nonce) if nonce is not None else None
        if nonce is None or sent is None or now - sent > PROOF_TIMEOUT_S:
            return None
        url = verify_proof(self.key, nonce, data)
        if url is not None:
            del self._pending[nonce]
        return url

    def _prune(self, now: float) -> None:
        for nonce in [n for n, at in self._pending.items() if now - at > PROOF_TIMEOUT_S]:
            del self._pending[nonce]
        for sender in [s for s, at in self._last.items() if now - at > CHALLENGE_INTERVAL_S]:
            del self._last[sender]


def prove(host: str, ack_port: int, key: bytes, timeout: float = PROOF_TIMEOUT_S) -> str | None:
    """Challenge the beacon on ``host`` (an mDNS answer's address) and return the URL it proves, or None."""
    challenges = Challenges(key)
    deadline = time.monotonic() + timeout
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_DGRAM) as sock:
        sock.settimeout(0.2)
        while (now := time.monotonic()) < deadline:
            datagram = challenges.due(host, now)  # again every second: UDP may lose one
            if datagram is not None:
                with contextlib.suppress(OSError):
                    sock.sendto(datagram, (host, ack_port))
            try:
                data, _ = sock.recvfrom(1024)
            except (TimeoutError, OSError):
                continue
            url = challenges.answer(data, time.monotonic())
            if url is not None:
                return url
    return None
