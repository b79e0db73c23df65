"""Discovery never hands out a password (issue 29 #3). The first answer to the UDP beacon used to win, as plain
``mqtt://``, and the agent logged in there with its broker password. Real agent processes against a rogue
beacon in the test (broadcasts pointing at a rogue "broker" that records what it is sent; on 127.0.0.2, it
also answers challenges, with a proof signed by another key), and the real ``fleet-agent beacon`` with the
server's fleet key in front of the shipped Mosquitto config (authentication on, acl.example):

- a robot with a password and no pin refuses to discover, says how to enrol, and sends nothing anywhere;
- a robot with the fleet key follows only the beacon that proves the key, never the rogue that answers first;
- a robot pinned by ``tls_ca`` follows only ``mqtts://`` answers, where TLS is checked before any password.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from pathlib import Path

import certifi

from backend.core.broker_auth import set_broker_password
from backend.core.fleet_key import fleet_key, fleet_key_path
from fleet_protocol import Topics
from fleet_protocol.discovery import parse_challenge, proof
from tests.deploy.test_mosquitto import DEPLOY, Client, shipped_broker
from tests.support.procs import VENV_BIN, ManagedProcess, base_env, free_port, wait_for

T = Topics()
PASSWORD = "robot-broker-password-0123456789"
SERVER_PASSWORD = "server-password-0123456789abcdef"
ROGUE_HOST = "127.0.0.2"  # another "host" on the loopback network: the rogue's own ACK port there


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class RogueBroker:
    """Where the rogue beacon sends robots: accepts every connection and keeps its first bytes."""

    def __init__(self) -> None:
        self.port = free_port()
        self.got: list[bytes] = []
        self._sock = socket.create_server(("127.0.0.1", self.port))
        self._sock.settimeout(0.1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            with conn:
                conn.settimeout(2.0)
                with contextlib.suppress(OSError):
                    self.got.append(conn.recv(4096))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._sock.close()


class RogueBeacon:
    """Broadcasts ``payload`` to the robots' beacon port every 50 ms (five times the real beacon's rate here)
    from ``ROGUE_HOST``; answers every challenge on its own ACK port with a proof under another key."""

    def __init__(self, udp_port: int, ack_port: int, payload: bytes, forged_url: str) -> None:
        self.payload = payload
        self.challenged = threading.Event()
        self._udp_port, self._forged_url = udp_port, forged_url
        self._tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._tx.bind((ROGUE_HOST, 0))
        self._rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._rx.bind((ROGUE_HOST, ack_port))
        self._rx.settimeout(0.05)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(OSError):
                self._tx.sendto(self.payload, ("127.0.0.1", self._udp_port))
            try:
                data, addr = self._rx.recvfrom(256)
            except TimeoutError:
                continue
            nonce = parse_challenge(data)
            if nonce is not None:
                self._rx.sendto(proof(b"\x07" * 32, nonce, self._forged_url), addr)
                self.challenged.set()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._tx.close()
        self._rx.close()


def _agent(robot_id: str, config: Path, workdir: Path, **env: str) -> ManagedProcess:
    """``fleet-agent --simulate`` with no ``--broker``: it must discover."""
    agent = ManagedProcess(
        f"agent-{robot_id}",
        [str(VENV_BIN / "fleet-agent"), "--robot-id", robot_id, "--simulate", "--config", str(config)],
        base_env(**env),
        workdir,
    )
    agent.zygote = "agent"
    return agent


def _discovery_table(udp: int, ack: int) -> str:
    return f"[discovery]\nmdns = false\nudp_port = {udp}\nack_port = {ack}\n"


def test_a_robot_with_a_password_and_no_pin_never_sends_it_to_a_beacon(workdir: Path) -> None:
    udp, ack = _free_udp_port(), _free_udp_port()
    rogue = RogueBroker()
    beacon = RogueBeacon(udp, ack, f"127.0.0.1:{rogue.port}".encode(), f"mqtt://127.0.0.1:{rogue.port}")
    config = workdir / "agent.toml"
    config.write_text(_discovery_table(udp, ack))
    agent = _agent("disc-pw", config, workdir, FLEET_AGENT_PASSWORD=PASSWORD)
    agent.start()
    try:
        wait_for(lambda: not agent.alive() or rogue.got, 30, what="the agent to refuse discovery")
    finally:
        code = agent.stop()
        beacon.close()
        rogue.close()
    assert rogue.got == [], f"the robot logged in at the first beacon's broker: {rogue.got[0][:60]!r}"
    out = agent.output()
    assert code == 2, out[-2000:]
    assert "discovery refused" in out and "fleet-server robots add" in out and "set `broker`" in out
    assert PASSWORD not in out


def test_a_robot_with_the_fleet_key_follows_only_the_beacon_that_proves_it(workdir: Path) -> None:
    key = fleet_key(workdir / "server-data")  # what the server creates in FLEET_DATA_DIR
    passwd = workdir / "passwd"
    set_broker_password(passwd, "fleet-server", SERVER_PASSWORD)
    set_broker_password(passwd, "disc-key", PASSWORD)
    files = {"passwd": passwd.read_text(), "acl": (DEPLOY / "mosquitto" / "acl.example").read_text()}
    udp, ack = _free_udp_port(), _free_udp_port()
    with shipped_broker("auth", files) as b:
        server = Client(b.port, username="fleet-server", password=SERVER_PASSWORD, subscribe=(T.status("disc-key"),))
        server.wait_connected()
        rogue = RogueBroker()
        rogue_url = f"mqtt://127.0.0.1:{rogue.port}"
        beacon = RogueBeacon(udp, ack, f"127.0.0.1:{rogue.port}".encode(), rogue_url)
        config = workdir / "agent.toml"
        config.write_text(f'fleet_key = "{key.hex()}"\n' + _discovery_table(udp, ack))
        agent = _agent("disc-key", config, workdir, FLEET_AGENT_PASSWORD=PASSWORD)
        real = ManagedProcess(
            "beacon-real",
            [
                str(VENV_BIN / "fleet-agent"),
                "beacon",
                "--broker-url",
                f"mqtt://127.0.0.1:{b.port}",
                "--no-mdns",
                *("--udp-port", str(udp), "--ack-port", str(ack), "--target", "127.0.0.1", "--interval", "0.2"),
                *("--fleet-key-file", str(fleet_key_path(workdir / "server-data"))),
            ],
            base_env(),
            workdir,
        )
        agent.start()
        try:
            # the rogue is heard first: it is challenged, and answers with a proof under another key
            assert beacon.challenged.wait(30), "the robot never challenged the rogue beacon"
            wait_for(lambda: "does not prove the fleet key" in agent.output(), 10, what="the forged proof refused")
            real.start()
            server.wait_for_topic(T.status("disc-key"))
            wait_for(lambda: b'"online":true' in server.got[-1][1], 20, what="the robot online on the real broker")
        finally:
            agent.stop()
            real.stop()
            beacon.close()
            rogue.close()
            server.close()
    assert rogue.got == [], f"the robot logged in at the rogue's broker: {rogue.got[0][:60]!r}"
    out = agent.output()
    assert f"broker mqtt://127.0.0.1:{b.port} announced by the beacon at 127.0.0.1 (fleet key verified)" in out
    assert PASSWORD not in out and key.hex() not in out
    assert "ACK from 127.0.0.1" in real.output()


def test_a_robot_pinned_by_tls_ca_follows_only_mqtts_answers(workdir: Path) -> None:
    udp, ack = _free_udp_port(), _free_udp_port()
    plain, tls = RogueBroker(), RogueBroker()
    beacon = RogueBeacon(udp, ack, f"127.0.0.1:{plain.port}".encode(), f"mqtt://127.0.0.1:{plain.port}")
    config = workdir / "agent.toml"
    config.write_text(f'tls_ca = "{certifi.where()}"\n' + _discovery_table(udp, ack))
    agent = _agent("disc-tls", config, workdir, FLEET_AGENT_PASSWORD=PASSWORD)
    agent.start()
    try:
        wait_for(
            lambda: "this robot only follows mqtts:// (tls_ca)" in agent.output() or plain.got,
            30,
            what="the plain answer ignored",
        )
        assert plain.got == [], f"the robot logged in at a plain mqtt:// broker: {plain.got[0][:60]!r}"
        beacon.payload = f"mqtts://127.0.0.1:{tls.port}".encode()  # an answer it may follow: TLS first
        wait_for(lambda: tls.got, 30, what="the robot's TLS connection")
    finally:
        agent.stop()
        beacon.close()
        plain.close()
        tls.close()
    assert plain.got == []
    assert all(hello.startswith(b"\x16\x03") for hello in tls.got), tls.got  # a TLS ClientHello, nothing else
    assert not any(PASSWORD.encode() in data for data in tls.got)
    assert f"broker mqtts://127.0.0.1:{tls.port} announced by UDP broadcast" in agent.output()
