"""Broker discovery both ways, with the real base-station beacon (`fleet-agent beacon`) and a real broker:
mDNS (`_mqtt._tcp`, python-zeroconf on loopback) and the seed's UDP broadcast (IP to port 7000, ``ACK``
back on 7002; free ports here). A robot started without --broker comes online by itself."""

from __future__ import annotations

import contextlib
import ipaddress
import socket
import subprocess
import time
from pathlib import Path

import pytest

from fleet_protocol import Topics
from tests.support.procs import VENV_BIN, ManagedProcess, base_env, free_port, wait_for

T = Topics()


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _bound_udp_ports() -> set[int]:
    """Local ports of every IPv4 UDP socket on this host."""
    lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    return {int(line.split()[1].rsplit(":", 1)[1], 16) for line in lines}


@pytest.fixture
def beacon(broker, workdir: Path):
    procs: list[ManagedProcess] = []

    def _start(*args: str, url: str | None = None) -> ManagedProcess:
        """``fleet-agent beacon`` announcing ``url`` (default: the test broker); stopped after the test."""
        p = ManagedProcess(
            f"beacon-{len(procs)}",
            [str(VENV_BIN / "fleet-agent"), "beacon", "--broker-url", url or broker.url, *args],
            base_env(),
            workdir,
        )
        p.start()
        procs.append(p)
        return p

    yield _start
    for p in procs:
        p.stop()


def _discover(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(VENV_BIN / "fleet-agent"), "discover", "--timeout", "10", *args],
        capture_output=True,
        text=True,
        timeout=30,
        env=base_env(),
    )


def test_mdns_discovery_finds_the_broker_and_the_robot_comes_online(broker, beacon, workdir, mqtt_probe):
    beacon("--no-udp", "--mdns-interface", "127.0.0.1")
    r = _discover("--no-udp", "--mdns-interface", "127.0.0.1")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"mqtt://127.0.0.1:{broker.port}"
    probe = mqtt_probe(T.status("disc-0"))
    config = workdir / "agent.toml"
    config.write_text('[discovery]\nudp = false\nmdns_interfaces = ["127.0.0.1"]\n')
    agent = ManagedProcess(
        "agent-disc-0",
        [str(VENV_BIN / "fleet-agent"), "--robot-id", "disc-0", "--simulate", "--config", str(config)],
        base_env(),
        workdir,
    )
    agent.start()
    try:
        probe.wait(lambda m: m.topic == T.status("disc-0") and b'"online":true' in m.payload, 20)
    finally:
        agent.stop()
    assert f"broker mqtt://127.0.0.1:{broker.port} found by mDNS" in agent.output()


def test_udp_broadcast_discovery_acks_and_connects(broker, beacon, workdir, mqtt_probe):
    udp, ack = _free_udp_port(), _free_udp_port()
    b = beacon(
        "--no-mdns", "--udp-port", str(udp), "--ack-port", str(ack), "--target", "127.0.0.1", "--interval", "0.2"
    )
    probe = mqtt_probe(T.status("disc-1"))
    config = workdir / "agent.toml"
    config.write_text(f"[discovery]\nmdns = false\nudp_port = {udp}\nack_port = {ack}\n")
    agent = ManagedProcess(
        "agent-disc-1",
        [str(VENV_BIN / "fleet-agent"), "--robot-id", "disc-1", "--simulate", "--config", str(config)],
        base_env(),
        workdir,
    )
    agent.start()
    try:
        probe.wait(lambda m: m.topic == T.status("disc-1") and b'"online":true' in m.payload, 20)
    finally:
        agent.stop()
    b.stop()
    assert "ACK from 127.0.0.1" in b.output()
    assert f"broker mqtt://127.0.0.1:{broker.port} announced by UDP broadcast" in agent.output()


def test_the_old_frameworks_bare_ip_broadcast_is_acked_and_followed(broker, workdir, mqtt_probe):
    """The seed's laptop module broadcasts only the IP (the broker port is implied): emulate it exactly,
    with the ACK socket it listens on, and point the robot's default_port at the test broker."""
    udp, ack_port = _free_udp_port(), _free_udp_port()
    probe = mqtt_probe(T.status("disc-3"))
    config = workdir / "agent3.toml"
    config.write_text(
        f"[discovery]\nmdns = false\nudp_port = {udp}\nack_port = {ack_port}\ndefault_port = {broker.port}\n"
    )
    agent = ManagedProcess(
        "agent-disc-3",
        [str(VENV_BIN / "fleet-agent"), "--robot-id", "disc-3", "--simulate", "--config", str(config)],
        base_env(),
        workdir,
    )
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", ack_port))
        rx.settimeout(0.3)
        agent.start()
        try:
            acked = None
            deadline = time.monotonic() + 20
            while acked is None and time.monotonic() < deadline:
                tx.sendto(b"127.0.0.1", ("127.0.0.1", udp))
                with contextlib.suppress(TimeoutError):
                    acked = rx.recvfrom(64)
            assert acked is not None and acked[0] == b"ACK", "the robot never acknowledged the broadcast"
            probe.wait(lambda m: m.topic == T.status("disc-3") and b'"online":true' in m.payload, 20)
        finally:
            agent.stop()


def test_beacon_target_from_url_or_ip() -> None:
    from robot_agent.cli import _beacon_target

    assert _beacon_target("mqtt://127.0.0.1:1884", None, None) == ("127.0.0.1", 1884)
    assert _beacon_target("mqtt://localhost", None, None) == ("127.0.0.1", 1883)
    assert _beacon_target(None, "10.1.2.3", 1885) == ("10.1.2.3", 1885)
    ip, port = _beacon_target("mqtt://0.0.0.0:1883", None, None)  # this host's LAN address
    assert port == 1883 and not ipaddress.IPv4Address(ip).is_unspecified
    with pytest.raises(ValueError, match="not both"):
        _beacon_target("mqtt://127.0.0.1:1884", "10.0.0.1", None)
    with pytest.raises(ValueError):
        _beacon_target(None, "not-an-ip", None)


def test_explicit_broker_wins_over_discovery(broker, beacon, workdir, mqtt_probe):
    # a beacon advertising a port where nothing listens: a robot following it would never come online
    udp, ack = _free_udp_port(), _free_udp_port()
    p = beacon(
        "--no-mdns",
        "--udp-port",
        str(udp),
        "--ack-port",
        str(ack),
        "--target",
        "127.0.0.1",
        "--interval",
        "0.2",
        url=f"mqtt://127.0.0.1:{free_port()}",
    )
    wait_for(lambda: "advertising mqtt://127.0.0.1:" in p.output(), 20, what="beacon broadcasting")
    probe = mqtt_probe(T.status("disc-2"))
    config = workdir / "agent2.toml"
    config.write_text(f"[discovery]\nmdns = false\nudp_port = {udp}\nack_port = {ack}\n")
    agent = ManagedProcess(
        "agent-disc-2",
        [
            str(VENV_BIN / "fleet-agent"),
            "--robot-id",
            "disc-2",
            "--simulate",
            "--broker",
            broker.url,
            "--config",
            str(config),
        ],
        base_env(),
        workdir,
    )
    agent.start()
    try:
        probe.wait(lambda m: m.topic == T.status("disc-2") and b'"online":true' in m.payload, 20)
        assert udp not in _bound_udp_ports()  # the robot never even listened for the beacon
    finally:
        agent.stop()
    p.stop()
    assert "ACK from" not in p.output()
    assert "discovering" not in agent.output()
