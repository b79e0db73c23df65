"""Finding the broker without configuring an IP: mDNS/DNS-SD and the seed's UDP broadcast.

Robot side: :func:`discover_broker` browses ``_mqtt._tcp`` (python-zeroconf) and listens for the seed's
broadcast (the base station's IP on UDP 7000; we answer ``ACK`` to the sender on 7002, as the seed's
robots do) at the same time; the first answer wins. An explicit ``--broker`` skips all of this.

Base-station side: :func:`advertise_mdns` registers the broker as ``_mqtt._tcp``; :func:`udp_beacon`
broadcasts its IP the seed's way (today's robots keep finding it).

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

if TYPE_CHECKING:
    from robot_agent.config import DiscoveryConfig

log = logging.getLogger(__name__)

MQTT_SERVICE = "_mqtt._tcp.local."
BEACON_PORT = 7000
ACK_PORT = 7002
ACK = b"ACK"


def parse_beacon(payload: bytes, sender_ip: str, default_port: int = 1883) -> str | None:
    """Broker URL from a broadcast payload: ``"IP"`` (the seed), ``"IP:PORT"`` or ``"mqtt://IP:PORT"``."""
    try:
        text = payload.decode("utf-8").strip()
    except UnicodeDecodeError:
        return None
    if text.startswith("mqtt://"):
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
    return f"mqtt://{ip}:{port}"


def listen_udp_broadcast(
    port: int = BEACON_PORT,
    ack_port: int = ACK_PORT,
    timeout: float | None = None,
    bind: str = "",
    default_port: int = 1883,
    stop: threading.Event | None = None,
) -> str | None:
    """Wait for the seed's broadcast; ACK it and return the broker URL (None on timeout/stop)."""
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
            url = parse_beacon(data, addr[0], default_port)
            if url is None:
                log.debug("ignoring discovery datagram %r from %s", data[:60], addr[0])
                continue
            with contextlib.suppress(OSError):
                sock.sendto(ACK, (addr[0], ack_port))
            log.info("broker %s announced by UDP broadcast from %s", url, addr[0])
            return url
    return None


def browse_mdns(
    timeout: float | None = None,
    interfaces: list[str] | None = None,
    stop: threading.Event | None = None,
) -> str | None:
    """Browse ``_mqtt._tcp`` and return the first broker's URL (None on timeout/stop)."""
    from zeroconf import InterfaceChoice, ServiceBrowser, ServiceStateChange, Zeroconf

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
                if addrs:
                    host = addrs[0] if ":" not in addrs[0] else f"[{addrs[0]}]"
                    url = f"mqtt://{host}:{info.port}"
                    log.info("broker %s found by mDNS (%s)", url, name)
                    return url
        return None
    finally:
        browser.cancel()
        zc.close()


@dataclass
class DiscoveryOptions:
    mdns: bool = True
    udp: bool = True
    udp_port: int = BEACON_PORT
    ack_port: int = ACK_PORT
    default_port: int = 1883
    mdns_interfaces: list[str] | None = None
    udp_bind: str = ""


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
            url = fn(timeout=timeout, stop=done, **kw)
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
                kwargs={"interfaces": opts.mdns_interfaces},
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


async def discover(config: DiscoveryConfig, stop: asyncio.Event) -> str | None:
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
    )
    halt = threading.Event()
    waiter = asyncio.create_task(stop.wait())
    try:
        log.info("no broker configured: discovering (mDNS %s, UDP broadcast port %d)", config.mdns, config.udp_port)
        task = asyncio.create_task(asyncio.to_thread(discover_broker, opts, config.timeout_s or None, halt))
        await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
        halt.set()
        return await task
    finally:
        waiter.cancel()


# ----------------------------------------------------------------------------------------------------
# Base-station side
# ----------------------------------------------------------------------------------------------------


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
) -> MdnsAdvertisement:
    """Register the broker as ``_mqtt._tcp`` on the local network; ``close()`` withdraws it."""
    from zeroconf import InterfaceChoice, ServiceInfo, Zeroconf

    info = ServiceInfo(
        MQTT_SERVICE,
        f"{name}.{MQTT_SERVICE}",
        addresses=[socket.inet_aton(ip)],
        port=port,
        properties=properties or {"app": "mollusca-fleet"},
        server=f"{socket.gethostname().split('.')[0] or 'fleet'}.local.",
    )
    zc = Zeroconf(interfaces=interfaces if interfaces else InterfaceChoice.All)
    zc.register_service(info, allow_name_change=True)
    return MdnsAdvertisement(zc, info)


@dataclass
class BeaconResult:
    acks: list[str] = field(default_factory=list)
    sent: int = 0


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
) -> BeaconResult:
    """Broadcast the broker IP every ``interval`` seconds the seed's way and collect ``ACK`` senders.

    The payload is the bare IP (what the seed's robots parse) when the broker is on 1883, else
    ``IP:PORT``. Unlike the seed it keeps going after the first ACK (a fleet has many robots) unless
    ``until_first_ack``; it stops on ``stop`` or after ``max_time``.
    """
    payload = (ip if broker_port == 1883 else f"{ip}:{broker_port}").encode()
    result = BeaconResult()
    deadline = None if max_time is None else time.monotonic() + max_time
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
                data, addr = rx.recvfrom(64)
            except TimeoutError:
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
