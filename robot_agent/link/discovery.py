"""Finding the broker without configuring an IP: mDNS/DNS-SD and the seed's UDP broadcast.

Robot side: :func:`discover_broker` browses ``_mqtt._tcp`` (python-zeroconf) and listens for the seed's
broadcast (the base station's IP on UDP 7000; we answer ``ACK`` to the sender on 7002, as the seed's
robots do) at the same time; the first answer that passes the robot's **pins** wins. An explicit
``--broker`` skips all of this. The base station's side is robot_agent/link/beacon.py.

Pins (issue 29 #3: anyone on the network can broadcast, and the first answer used to get the robot's broker
password): with the **fleet key** only an answer proven by the beacon counts (a challenge with fresh random
bytes to the sender's ACK port, answered with the broker URL signed by the key: fleet_protocol/discovery.py);
with only ``tls_ca``, only an ``mqtts://`` answer (the TLS handshake against that CA is the proof). An agent
with a broker password and neither pin does not discover at all (robot_agent/link/pins.py).

zeroconf is imported lazily (the ``pi`` extra); without it only the UDP way is used.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from fleet_common.ratelimit import RateLimitedLogger
from fleet_protocol.discovery import proof_nonce
from robot_agent.link.pins import Challenges, Pins, prove

if TYPE_CHECKING:
    from robot_agent.config import DiscoveryConfig

log = logging.getLogger(__name__)
ignored_log = RateLimitedLogger(log, interval_s=10.0)

MQTT_SERVICE = "_mqtt._tcp.local."
BEACON_PORT = 7000
ACK_PORT = 7002
ACK = b"ACK"


def parse_beacon(payload: bytes, sender_ip: str, default_port: int = 1883) -> str | None:
    """Broker URL from a broadcast payload: ``"IP"`` (the seed), ``"IP:PORT"``, ``"mqtt://IP:PORT"`` or
    ``"mqtts://IP[:PORT]"`` (TLS, default port 8883)."""
    try:
        text = payload.decode("utf-8").strip()
    except UnicodeDecodeError:
        return None
    scheme = "mqtt"
    if text.startswith("mqtts://"):
        scheme, text, default_port = "mqtts", text[len("mqtts://") :], 8883
    elif text.startswith("mqtt://"):
        text = text[len("mqtt://") :]
    host, _, port_text = text.partition(":")
    try:
        ip = ipaddress.IPv4Address(host)
        port = int(port_text) if port_text else default_port
    except ValueError:
        return None
    if not 0 < port < 65536:
        return None
    if ip.is_unspecified:
        ip = ipaddress.IPv4Address(sender_ip)
    return f"{scheme}://{ip}:{port}"


def listen_udp_broadcast(
    port: int = BEACON_PORT,
    ack_port: int = ACK_PORT,
    timeout: float | None = None,
    bind: str = "",
    default_port: int = 1883,
    stop: threading.Event | None = None,
    pins: Pins | None = None,
) -> str | None:
    """Wait for the seed's broadcast; ACK it and return the broker URL (None on timeout/stop). With a fleet
    key the broadcast only names a host to challenge, and the URL is the one its proof carries."""
    pins = pins or Pins()
    challenges = Challenges(pins.fleet_key) if pins.fleet_key is not None else None
    deadline = None if timeout is None else time.monotonic() + timeout
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((bind, port))
        sock.settimeout(0.2)
        while not (stop is not None and stop.is_set()):
            if deadline is not None and time.monotonic() >= deadline:
                return None
            try:
                data, addr = sock.recvfrom(1024)
            except TimeoutError:
                continue
            if challenges is not None:
                url = challenges.answer(data, time.monotonic())
                if url is None:
                    _challenge_sender(sock, challenges, data, addr[0], ack_port, default_port)
                    continue
                how = f"the beacon at {addr[0]} (fleet key verified)"
            else:
                url = parse_beacon(data, addr[0], default_port)
                if url is None:
                    log.debug("ignoring discovery datagram %r from %s", data[:60], addr[0])
                    continue
                if not pins.accepts_unproven(url):
                    why = "ignoring broker %s from %s: this robot only follows mqtts:// (tls_ca)"
                    ignored_log.warning(addr[0], why, url, addr[0])
                    continue
                how = f"UDP broadcast from {addr[0]}"
            with contextlib.suppress(OSError):
                sock.sendto(ACK, (addr[0], ack_port))
            log.info("broker %s announced by %s", url, how)
            return url
    return None


def _challenge_sender(
    sock: socket.socket, challenges: Challenges, data: bytes, sender: str, ack_port: int, default_port: int
) -> None:
    """A pinned robot's answer to anything but a valid proof: a broadcast gets a challenge, the rest is
    ignored (a forged or late proof is logged)."""
    if parse_beacon(data, sender, default_port) is None:
        if proof_nonce(data) is not None:
            ignored_log.warning(sender, "ignoring a beacon answer from %s: it does not prove the fleet key", sender)
        return
    datagram = challenges.due(sender, time.monotonic())
    if datagram is not None:
        with contextlib.suppress(OSError):
            sock.sendto(datagram, (sender, ack_port))


def browse_mdns(
    timeout: float | None = None,
    interfaces: list[str] | None = None,
    stop: threading.Event | None = None,
    pins: Pins | None = None,
    ack_port: int = ACK_PORT,
) -> str | None:
    """Browse ``_mqtt._tcp`` and return the first broker's URL that passes ``pins`` (None on timeout/stop)."""
    from zeroconf import InterfaceChoice, ServiceBrowser, ServiceStateChange, Zeroconf

    pins = pins or Pins()
    found: list[str] = []
    event = threading.Event()

    def on_change(zeroconf: Any, service_type: str, name: str, state_change: Any) -> None:
        if state_change in (ServiceStateChange.Added, ServiceStateChange.Updated):
            found.append(name)
            event.set()

    zc = Zeroconf(interfaces=interfaces if interfaces else InterfaceChoice.All)
    browser = ServiceBrowser(zc, MQTT_SERVICE, handlers=[on_change])
    deadline = None if timeout is None else time.monotonic() + timeout
    try:
        while not (stop is not None and stop.is_set()):
            left = 0.2 if deadline is None else min(0.2, deadline - time.monotonic())
            if left <= 0:
                return None
            if not event.wait(left):
                continue
            event.clear()
            while found:
                name = found.pop(0)
                info = zc.get_service_info(MQTT_SERVICE, name, timeout=2000)
                if info is None or not info.port:
                    continue
                addrs = [a for a in info.parsed_addresses() if ":" not in a] or info.parsed_addresses()
                if not addrs:
                    continue
                url = _checked_mdns_url(addrs[0], info.port, info.properties or {}, name, pins, ack_port)
                if url is not None:
                    return url
        return None
    finally:
        browser.cancel()
        zc.close()


def _checked_mdns_url(
    addr: str, port: int, properties: dict[Any, Any], name: str, pins: Pins, ack_port: int
) -> str | None:
    host = addr if ":" not in addr else f"[{addr}]"
    scheme = "mqtts" if properties.get(b"scheme") == b"mqtts" else "mqtt"
    url = f"{scheme}://{host}:{port}"
    if pins.fleet_key is not None:
        proven = prove(addr, ack_port, pins.fleet_key)
        if proven is None:
            ignored_log.warning(addr, "ignoring broker %s found by mDNS (%s): its host proves no fleet key", url, name)
            return None
        log.info("broker %s found by mDNS (%s), fleet key verified by the beacon at %s", proven, name, addr)
        return proven
    if not pins.accepts_unproven(url):
        ignored_log.warning(addr, "ignoring broker %s found by mDNS: this robot only follows mqtts:// (tls_ca)", url)
        return None
    log.info("broker %s found by mDNS (%s)", url, name)
    return url


@dataclass
class DiscoveryOptions:
    mdns: bool = True
    udp: bool = True
    udp_port: int = BEACON_PORT
    ack_port: int = ACK_PORT
    default_port: int = 1883
    mdns_interfaces: list[str] | None = None
    udp_bind: str = ""
    pins: Pins = field(default_factory=Pins)


def discover_broker(
    options: DiscoveryOptions | None = None,
    timeout: float | None = None,
    stop: threading.Event | None = None,
) -> str | None:
    """Run every enabled method in parallel; the first broker URL found wins (None on timeout/stop)."""
    opts = options or DiscoveryOptions()
    done = threading.Event()
    result: list[str] = []
    errors: list[str] = []
    lock = threading.Lock()

    def runner(fn: Callable[..., str | None], name: str, **kw: Any) -> None:
        try:
            url = fn(timeout=timeout, stop=done, pins=opts.pins, **kw)
        except ImportError:
            errors.append(f"{name}: zeroconf is not installed")
            log.info("mDNS discovery unavailable (pip install zeroconf)")
            return
        except OSError as exc:
            errors.append(f"{name}: {exc}")
            log.warning("%s discovery failed: %s", name, exc)
            return
        if url:
            with lock:
                if not result:
                    result.append(url)
            done.set()

    threads = []
    if opts.mdns:
        threads.append(
            threading.Thread(
                target=runner,
                args=(browse_mdns, "mDNS"),
                kwargs={"interfaces": opts.mdns_interfaces, "ack_port": opts.ack_port},
                daemon=True,
            )
        )
    if opts.udp:
        threads.append(
            threading.Thread(
                target=runner,
                args=(listen_udp_broadcast, "UDP"),
                kwargs={
                    "port": opts.udp_port,
                    "ack_port": opts.ack_port,
                    "default_port": opts.default_port,
                    "bind": opts.udp_bind,
                },
                daemon=True,
            )
        )
    for t in threads:
        t.start()
    try:
        while any(t.is_alive() for t in threads) and not done.is_set():
            if stop is not None and stop.is_set():
                break
            time.sleep(0.05)
    finally:
        done.set()
        for t in threads:
            t.join(5)
    return result[0] if result else None


async def discover(config: DiscoveryConfig, stop: asyncio.Event, pins: Pins | None = None) -> str | None:
    """The agent's way in without ``--broker``: :func:`discover_broker` in a thread (it blocks), until a
    broker is found, ``stop`` is set or ``config.timeout_s`` passes."""
    opts = DiscoveryOptions(
        mdns=config.mdns,
        udp=config.udp,
        udp_port=config.udp_port,
        ack_port=config.ack_port,
        default_port=config.default_port,
        mdns_interfaces=list(config.mdns_interfaces) or None,
        udp_bind=config.udp_bind,
        pins=pins or Pins(),
    )
    halt = threading.Event()
    waiter = asyncio.create_task(stop.wait())
    try:
        log.info(
            "no broker configured: discovering (mDNS %s, UDP broadcast port %d, pin: %s)",
            config.mdns,
            config.udp_port,
            opts.pins.describe(),
        )
        task = asyncio.create_task(asyncio.to_thread(discover_broker, opts, config.timeout_s or None, halt))
        await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
        halt.set()
        return await task
    finally:
        waiter.cancel()
