"""Base-station side of discovery (``fleet-agent beacon``): :func:`advertise_mdns` registers the broker as
``_mqtt._tcp``; :func:`udp_beacon` broadcasts its IP the seed's way (today's robots keep finding it) and
answers pinned robots' challenges with the broker URL signed by the fleet key (fleet_protocol/discovery.py).
The robot side is robot_agent/link/discovery.py.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fleet_common.ratelimit import RateLimitedLogger
from fleet_protocol.discovery import parse_challenge, parse_fleet_key, proof
from robot_agent.link.discovery import ACK, ACK_PORT, BEACON_PORT, MQTT_SERVICE

log = logging.getLogger(__name__)
refused_log = RateLimitedLogger(log, interval_s=30.0)
#: proofs sent per second at most, whoever asks (a proof is larger than a challenge: no amplifier for floods)
MAX_PROOFS_PER_S = 20


@dataclass
class MdnsAdvertisement:
    zeroconf: Any
    info: Any

    def close(self) -> None:
        try:
            self.zeroconf.unregister_service(self.info)
        finally:
            self.zeroconf.close()


def advertise_mdns(
    ip: str,
    port: int = 1883,
    name: str = "Mollusca Fleet broker",
    interfaces: list[str] | None = None,
    properties: dict[str, str] | None = None,
    scheme: str = "mqtt",
) -> MdnsAdvertisement:
    """Register the broker as ``_mqtt._tcp`` on the local network (TXT ``scheme=mqtts`` for the TLS
    listener); ``close()`` withdraws it."""
    from zeroconf import InterfaceChoice, ServiceInfo, Zeroconf

    info = ServiceInfo(
        MQTT_SERVICE,
        f"{name}.{MQTT_SERVICE}",
        addresses=[socket.inet_aton(ip)],
        port=port,
        properties=properties or {"app": "mollusca-fleet", "scheme": scheme},
        server=f"{socket.gethostname().split('.')[0] or 'fleet'}.local.",
    )
    zc = Zeroconf(interfaces=interfaces if interfaces else InterfaceChoice.All)
    zc.register_service(info, allow_name_change=True)
    return MdnsAdvertisement(zc, info)


class FleetKeyFile:
    """The fleet key, read from the server's data directory when first needed: the server creates the file
    at its first start, which may come after the beacon's."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self._key: bytes | None = None

    def get(self) -> bytes | None:
        if self._key is None and self.path is not None:
            try:
                self._key = parse_fleet_key(self.path.read_text())
                log.info("fleet key loaded from %s: answering pinned robots' challenges", self.path)
            except (OSError, ValueError) as exc:
                refused_log.warning(
                    "key",
                    "challenge unanswered: fleet key %s not readable yet (%s); the server creates it",
                    self.path,
                    exc,
                )
        return self._key


@dataclass
class BeaconResult:
    acks: list[str] = field(default_factory=list)
    sent: int = 0
    proofs: int = 0


def udp_beacon(
    ip: str,
    broker_port: int = 1883,
    port: int = BEACON_PORT,
    ack_port: int = ACK_PORT,
    target: str = "<broadcast>",
    interval: float = 1.0,
    stop: threading.Event | None = None,
    until_first_ack: bool = False,
    max_time: float | None = None,
    on_ack: Callable[[str], None] | None = None,
    scheme: str = "mqtt",
    fleet_key: FleetKeyFile | None = None,
) -> BeaconResult:
    """Broadcast the broker IP every ``interval`` seconds the seed's way, collect ``ACK`` senders and answer
    challenges (when the fleet key is there).

    The payload is the bare IP (what the seed's robots parse) when the broker is plain MQTT on 1883, else
    ``IP:PORT`` (``mqtts://IP:PORT`` for TLS). Unlike the seed it keeps going after the first ACK (a fleet
    has many robots) unless ``until_first_ack``; it stops on ``stop`` or after ``max_time``.
    """
    if scheme == "mqtts":
        payload = f"mqtts://{ip}:{broker_port}".encode()
    else:
        payload = (ip if broker_port == 1883 else f"{ip}:{broker_port}").encode()
    url = f"{scheme}://{ip}:{broker_port}"
    result = BeaconResult()
    deadline = None if max_time is None else time.monotonic() + max_time
    proof_window, proofs_in_window = 0.0, 0
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx,
    ):
        tx.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        rx.bind(("", ack_port))
        rx.settimeout(0.1)
        next_send = 0.0
        while not (stop is not None and stop.is_set()):
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            if now >= next_send:
                try:
                    tx.sendto(payload, (target, port))
                    result.sent += 1
                except OSError as exc:
                    log.warning("beacon send failed: %s", exc)
                next_send = now + interval
            try:
                data, addr = rx.recvfrom(128)
            except TimeoutError:
                continue
            nonce = parse_challenge(data)
            if nonce is not None:
                key = fleet_key.get() if fleet_key is not None else None
                if key is None:
                    continue
                if now - proof_window >= 1.0:
                    proof_window, proofs_in_window = now, 0
                if proofs_in_window >= MAX_PROOFS_PER_S:
                    refused_log.warning("flood", "challenges beyond %d a second left unanswered", MAX_PROOFS_PER_S)
                    continue
                proofs_in_window += 1
                try:
                    rx.sendto(proof(key, nonce, url), addr)
                    result.proofs += 1
                except OSError as exc:
                    log.warning("proof to %s not sent: %s", addr[0], exc)
                continue
            if data.strip() == ACK:
                if addr[0] not in result.acks:
                    log.info("robot at %s acknowledged the broker address", addr[0])
                    result.acks.append(addr[0])
                if on_ack is not None:
                    on_ack(addr[0])
                if until_first_ack:
                    break
    return result
