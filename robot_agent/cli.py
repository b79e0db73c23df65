"""``fleet-agent``: run the robot agent, or ``discover`` / ``detect`` / ``calibrate``.

``fleet-agent --robot-id ID --broker mqtt://HOST:PORT [--simulate] ...`` runs the agent (CLI > env
``FLEET_AGENT_*`` > TOML ``--config`` > defaults). Exit status: 0 after a clean shutdown (SIGTERM/SIGINT),
2 for bad settings, 1 for a fatal error.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from collections.abc import Sequence
from typing import Any

from robot_agent import __version__

SUBCOMMANDS = ("run", "discover", "beacon", "enrol", "detect", "calibrate", "estop", "estop-button")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet-agent",
        description="Mollusca Fleet robot agent. Subcommands: discover, beacon, enrol, detect, calibrate, estop, "
        "estop-button (default: run).",
    )
    p.add_argument("--version", action="version", version=__version__)
    p.add_argument("--robot-id", dest="robot_id", help="robot id [A-Za-z0-9_-]{1,64}")
    p.add_argument("--broker", help="mqtt://HOST:PORT (omit to discover by mDNS / UDP broadcast)")
    p.add_argument(
        "--simulate",
        action="store_const",
        const=True,
        default=None,
        help="simulated robot (differential drive in a 4 m pool)",
    )
    p.add_argument(
        "--camera",
        action="store_const",
        const=True,
        default=None,
        help="also stream camera frames and AprilTag detections (simulated camera with --simulate)",
    )
    p.add_argument("--username", help="broker user name (also FLEET_AGENT_USERNAME)")
    p.add_argument(
        "--password",
        help="broker password; prefer FLEET_AGENT_PASSWORD or the config file (flags show in `ps`)",
    )
    p.add_argument("--tls-ca", dest="tls_ca", help="CA certificate of the broker's TLS listener (mqtts://)")
    p.add_argument("--prefix", help="topic prefix (default fleet)")
    p.add_argument("--config", help="TOML config file (also FLEET_AGENT_CONFIG)")
    p.add_argument("--keepalive", type=int, help="MQTT keepalive seconds (default 5)")
    p.add_argument("--position-rate", dest="position_rate", type=float, help="position rate Hz (default 20)")
    p.add_argument("--imu-rate", dest="imu_rate", type=float, help="imu rate Hz (default 10)")
    p.add_argument("--start-pose", dest="start_pose", help="X,Y,YAW of the simulated robot")
    p.add_argument(
        "--disturbances",
        action="store_const",
        const=True,
        default=None,
        help="simulator: water current, motor noise and asymmetry, Lighthouse noise, latency",
    )
    p.add_argument(
        "--no-current",
        dest="current",
        action="store_const",
        const=False,
        default=None,
        help="simulator: no water current (the other disturbances stay as configured)",
    )
    p.add_argument("--max-speed", dest="max_speed_mps", type=float, help="m/s at speed 1 (default 0.3)")
    p.add_argument(
        "--battery-start-pct",
        dest="battery_start_pct",
        type=float,
        help="charge of the simulated battery at start, %% (default 100)",
    )
    p.add_argument(
        "--no-health",
        dest="health",
        action="store_const",
        const=False,
        help="simulated robot without the default health stream",
    )
    p.add_argument("--buffer-size", dest="buffer_size", type=int, help="offline telemetry buffer (messages)")
    p.add_argument(
        "--replay-dir",
        dest="replay_dir",
        help="also keep the gap-repair replay ring (10 min of telemetry) on disk here, across restarts",
    )
    p.add_argument("--log-level", dest="log_level", help="DEBUG, INFO, WARNING, ERROR")
    return p


def _discover_main(argv: Sequence[str]) -> int:
    from robot_agent.config import ConfigError, load_settings
    from robot_agent.link.discovery import DiscoveryOptions, discover_broker
    from robot_agent.link.pins import Pins

    p = argparse.ArgumentParser(prog="fleet-agent discover", description="Print the broker URL found, then exit.")
    p.add_argument(
        "--config",
        help="the agent's config: follow only what it would (its fleet_key or tls_ca); default: any answer",
    )
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait (default 10)")
    p.add_argument("--no-mdns", action="store_true")
    p.add_argument("--no-udp", action="store_true")
    p.add_argument("--udp-port", type=int, default=7000)
    p.add_argument("--ack-port", type=int, default=7002)
    p.add_argument(
        "--mdns-interface",
        action="append",
        default=None,
        help="interface IP for mDNS (repeatable; default all)",
    )
    args = p.parse_args(list(argv))
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        pins = load_settings({"config": args.config}).discovery_pins() if args.config else Pins()
    except ConfigError as exc:
        print(f"fleet-agent discover: invalid settings: {exc}", file=sys.stderr)
        return 2
    opts = DiscoveryOptions(
        mdns=not args.no_mdns,
        udp=not args.no_udp,
        udp_port=args.udp_port,
        ack_port=args.ack_port,
        mdns_interfaces=args.mdns_interface,
        pins=pins,
    )
    url = discover_broker(opts, timeout=args.timeout)
    if url is None:
        print(f"no broker found within {args.timeout}s", file=sys.stderr)
        return 1
    print(url)
    return 0


def _local_ip() -> str:
    """The address robots should connect to: the one the default route leaves from."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # TEST-NET: no packet is sent for a UDP connect
            return str(s.getsockname()[0])
        except OSError:
            return "127.0.0.1"


def _beacon_target(url: str | None, ip: str | None, port: int | None) -> tuple[str, int]:
    """The IPv4 address and port the beacon announces, from ``--broker-url`` or ``--broker-ip/--broker-port``
    (the URL's scheme: :func:`_beacon_scheme`)."""
    import ipaddress
    import socket

    from robot_agent.config import parse_broker_url

    if url is not None:
        if ip is not None or port is not None:
            raise ValueError("give --broker-url or --broker-ip/--broker-port, not both")
        host, port = parse_broker_url(url)
        try:
            addr = ipaddress.IPv4Address(host)
        except ValueError:
            try:
                addr = ipaddress.IPv4Address(socket.gethostbyname(host))
            except OSError as exc:
                raise ValueError(f"cannot resolve broker host {host!r}: {exc}") from None
        ip = None if addr.is_unspecified else str(addr)
    elif ip is not None:
        ipaddress.IPv4Address(ip)  # the seed's robots parse a bare IPv4 address
    port = 1883 if port is None else port
    if not 0 < port < 65536:
        raise ValueError(f"bad broker port {port}")
    return ip or _local_ip(), port


def _beacon_scheme(url: str | None) -> str:
    """``mqtts`` for a TLS broker URL (``mqtts://``, ``ssl://``), else ``mqtt``."""
    return "mqtts" if url is not None and url.lower().startswith(("mqtts://", "ssl://")) else "mqtt"


def _beacon_main(argv: Sequence[str]) -> int:
    """Base-station side of discovery: advertise the broker by mDNS and by the seed's UDP broadcast, and
    prove the fleet key to pinned robots."""
    import threading
    from pathlib import Path

    from robot_agent.link.beacon import FleetKeyFile, advertise_mdns, udp_beacon
    from robot_agent.link.discovery import ACK_PORT, BEACON_PORT

    p = argparse.ArgumentParser(
        prog="fleet-agent beacon",
        description="Advertise the broker (mDNS _mqtt._tcp and UDP broadcast) until stopped.",
    )
    p.add_argument(
        "--broker-url",
        help="mqtt://HOST:PORT robots connect to (a host name is resolved; 0.0.0.0 = this host's LAN address)",
    )
    p.add_argument("--broker-ip", help="address robots connect to (default: this host's LAN address)")
    p.add_argument("--broker-port", type=int, default=None, help="broker port (default 1883)")
    p.add_argument("--no-mdns", action="store_true")
    p.add_argument("--no-udp", action="store_true")
    p.add_argument("--udp-port", type=int, default=BEACON_PORT)
    p.add_argument("--ack-port", type=int, default=ACK_PORT)
    p.add_argument("--target", default="<broadcast>", help="UDP destination (default: broadcast)")
    p.add_argument("--interval", type=float, default=1.0)
    p.add_argument("--mdns-interface", action="append", default=None)
    p.add_argument(
        "--fleet-key-file",
        type=Path,
        default=None,
        help="the server's fleet key (FLEET_DATA_DIR/fleet-key.secret): answer enrolled robots' challenges",
    )
    args = p.parse_args(list(argv))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        ip, broker_port = _beacon_target(args.broker_url, args.broker_ip, args.broker_port)
    except ValueError as exc:
        print(f"fleet-agent beacon: {exc}", file=sys.stderr)
        return 2
    args.broker_port = broker_port
    scheme = _beacon_scheme(args.broker_url)
    key = FleetKeyFile(args.fleet_key_file)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    ad = None if args.no_mdns else advertise_mdns(ip, args.broker_port, interfaces=args.mdns_interface, scheme=scheme)
    print(
        f"advertising {scheme}://{ip}:{args.broker_port} ({'no ' if args.no_mdns else ''}mDNS, "
        f"{'no ' if args.no_udp else ''}UDP broadcast on {args.udp_port}; "
        f"{'proving the fleet key of ' + str(args.fleet_key_file) if args.fleet_key_file else 'no fleet key'})",
        flush=True,
    )
    try:
        if args.no_udp:
            stop.wait()
        else:
            udp_beacon(
                ip,
                args.broker_port,
                args.udp_port,
                args.ack_port,
                args.target,
                args.interval,
                stop,
                on_ack=lambda who: logging.getLogger("beacon").info("ACK from %s", who),
                scheme=scheme,
                fleet_key=key,
            )
    finally:
        if ad is not None:
            ad.close()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list and args_list[0] in SUBCOMMANDS:
        sub, rest = args_list[0], args_list[1:]
        if sub == "discover":
            return _exit(_discover_main(rest), argv)
        if sub == "beacon":
            return _exit(_beacon_main(rest), argv)
        if sub == "enrol":
            from robot_agent.enrol import main_enrol

            return _exit(main_enrol(rest), argv)
        if sub in ("estop", "estop-button"):
            from robot_agent.estop_cli import main_button, main_estop

            return _exit((main_estop if sub == "estop" else main_button)(rest), argv)
        if sub == "detect":
            from robot_agent.vision.cli_detect import main_detect

            return _exit(main_detect(rest), argv)
        if sub == "calibrate":
            from robot_agent.vision.cli_calibrate import main_calibrate

            return _exit(main_calibrate(rest), argv)
        args_list = rest
    return _exit(_run_main(args_list), argv)


def _exit(code: int, argv: Sequence[str] | None) -> int:
    if argv is None:  # console script: exit with the status
        sys.exit(code)
    return code


def _run_main(argv: list[str]) -> int:
    from robot_agent.config import ConfigError, load_settings

    ns = build_parser().parse_args(argv)
    cli: dict[str, Any] = {k: v for k, v in vars(ns).items() if v is not None}
    try:
        settings = load_settings(cli)
    except ConfigError as exc:
        print(f"fleet-agent: invalid settings: {exc}", file=sys.stderr)
        return 2
    logging.basicConfig(
        level=getattr(logging, settings.log_level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        return asyncio.run(_amain(settings))
    except ConfigError as exc:
        print(f"fleet-agent: invalid settings: {exc}", file=sys.stderr)
        return 2


async def _amain(settings: Any) -> int:
    from robot_agent import debug_hooks
    from robot_agent.agent import Agent
    from robot_agent.config import ConfigError
    from robot_agent.link.discovery import discover
    from robot_agent.link.pins import refusal
    from robot_agent.motors import MotorConfigError
    from robot_agent.sensors.supervisor import SensorConfigError

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    debug = debug_hooks.debug_options()
    if debug is not None:
        debug_hooks.install(loop, debug)
    broker = settings.broker
    if broker is None:
        pins = settings.discovery_pins()
        refused = refusal(settings.password is not None, pins)
        if refused is not None:
            raise ConfigError(refused)
        broker = await discover(settings.discovery, stop, pins)
        if broker is None:
            if stop.is_set():
                return 0
            logging.getLogger("robot_agent").error("no broker found")
            return 1
    try:
        agent = Agent(settings, broker, debug)
    except (ConfigError, MotorConfigError, SensorConfigError, ValueError) as exc:
        raise ConfigError(str(exc)) from None
    await agent.run(stop)
    return 0
