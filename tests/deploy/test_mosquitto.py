"""deploy/mosquitto/ in a real Mosquitto: the shipped config starts cleanly, carries the largest camera
frame the protocol allows and refuses larger ones, keeps retained state and a persistent session's queued
QoS 1 messages across a broker restart (more than Mosquitto's default queue of 1000), and acl.example
confines each robot to its own topics. Also: the systemd units are valid and run real CLI commands."""

from __future__ import annotations

import contextlib
import shutil
import subprocess
import tempfile
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from fleet_protocol import MAX_CAMERA_PAYLOAD_BYTES, Topics
from tests.support.mqtt import MqttProbe
from tests.support.procs import VENV_BIN, base_env, free_port, wait_for, wait_port

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
#: the shipped authentication block (on) and the two test variants of it
AUTH_SHIPPED = (
    "allow_anonymous false\n#allow_anonymous true\npassword_file /mosquitto/auth/passwd\nacl_file /mosquitto/auth/acl\n"
)
AUTH_MODES = {
    "auth": AUTH_SHIPPED,
    # what mosquitto.conf tells a lab with robots on the old framework to do: swap the two comment marks
    "legacy": "#allow_anonymous false\nallow_anonymous true\npassword_file /mosquitto/auth/passwd\n"
    "acl_file /mosquitto/auth/acl\n",
    # test-only: no authentication, for tests about other settings (packet size, persistence)
    "open": "allow_anonymous true\n",
}


def _mosquitto() -> str:
    exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    if not Path(exe).exists():
        pytest.fail("mosquitto missing: scripts/ensure-system-deps.sh installs it")
    return exe


class ShippedBroker:
    """deploy/mosquitto/mosquitto.conf on a free loopback port. Only the container paths and the listener
    change (what deploy/README.md's sed does for systemd). ``mode``: "auth" as shipped (``auth_files`` are
    the passwd and acl), "legacy" (anonymous old-framework robots allowed, still under the ACL) or "open"."""

    def __init__(self, mode: str = "open", auth_files: dict[str, str] | None = None) -> None:
        # mosquitto started as root runs as the `mosquitto` user: its directories must be reachable for it
        self.dir = Path(tempfile.mkdtemp(prefix="fleet-mosquitto-"))
        self.dir.chmod(0o755)
        (self.dir / "data").mkdir(mode=0o777)
        (self.dir / "data").chmod(0o777)
        (self.dir / "auth").mkdir(mode=0o755)
        for name, text in (auth_files or {}).items():
            (self.dir / "auth" / name).write_text(text)
            (self.dir / "auth" / name).chmod(0o644)
        self.port = free_port()
        conf = (DEPLOY / "mosquitto" / "mosquitto.conf").read_text()
        for needle in ("\nlistener 1883\n", "persistence_location /mosquitto/data/\n", AUTH_SHIPPED):
            assert needle in conf, f"deploy/mosquitto/mosquitto.conf changed shape: {needle!r} not found"
        conf = conf.replace(AUTH_SHIPPED, AUTH_MODES[mode])
        conf = conf.replace("\nlistener 1883\n", f"\nlistener {self.port} 127.0.0.1\n")
        conf = conf.replace("/mosquitto/data/", f"{self.dir}/data/").replace("/mosquitto/auth/", f"{self.dir}/auth/")
        self.conf = self.dir / "mosquitto.conf"
        self.conf.write_text(conf)
        self.conf.chmod(0o644)
        self.log = self.dir / "mosquitto.log"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                [_mosquitto(), "-c", str(self.conf)], stdout=log, stderr=subprocess.STDOUT, env=base_env()
            )
        wait_port(self.port)

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()  # a clean stop writes the persistence file
            self.proc.wait(10)
            self.proc = None

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def close(self) -> None:
        try:
            if self.proc is not None and self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait(5)
        finally:
            shutil.rmtree(self.dir, ignore_errors=True)


#: Mosquitto warns about every ACL pattern without %u/%c; the e-stop line is one on purpose (acl.example)
ESTOP_PATTERN_WARNING = "Warning: ACL pattern 'fleet/estop' does not contain '%c' or '%u'."
HEARTBEAT_PATTERN_WARNING = "Warning: ACL pattern 'fleet/heartbeat' does not contain '%c' or '%u'."
SITE_PATTERN_WARNING = "Warning: ACL pattern 'fleet/site' does not contain '%c' or '%u'."
POSES_PATTERN_WARNING = "Warning: ACL pattern 'fleet/poses' does not contain '%c' or '%u'."


@contextlib.contextmanager
def shipped_broker(mode: str = "open", auth_files: dict[str, str] | None = None) -> Iterator[ShippedBroker]:
    b = ShippedBroker(mode, auth_files)
    try:
        b.start()
        yield b
        b.stop()
        out = b.output().replace(ESTOP_PATTERN_WARNING, "").replace(HEARTBEAT_PATTERN_WARNING, "")
        out = out.replace(SITE_PATTERN_WARNING, "").replace(POSES_PATTERN_WARNING, "")
        assert "Error" not in out and "Warning" not in out, out
    finally:
        b.close()


class Client:
    """A paho client that records what arrives and whether the broker dropped it."""

    def __init__(
        self,
        port: int,
        client_id: str | None = None,
        username: str | None = None,
        password: str | None = None,
        clean_session: bool = True,
        subscribe: tuple[str, ...] = (),
    ) -> None:
        self.got: list[tuple[str, bytes]] = []
        self.cond = threading.Condition()
        self.connected = threading.Event()
        self.dropped = threading.Event()
        self.refused: object = None
        self._subs = subscribe
        self._subacks = 0
        self.subscribed = threading.Event()
        self.c = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=client_id or f"t-{uuid.uuid4().hex[:8]}", clean_session=clean_session
        )
        if username:
            self.c.username_pw_set(username, password)
        self.c.on_connect = self._on_connect
        self.c.on_disconnect = lambda *_a: self.dropped.set()
        self.c.on_message = self._on_message
        self.c.on_subscribe = self._on_subscribe
        self.c.connect("127.0.0.1", port, keepalive=30)
        self.c.loop_start()

    def _on_connect(self, client: mqtt.Client, _u: object, _f: object, rc: object, _p: object) -> None:
        if getattr(rc, "is_failure", False):
            self.refused = rc
            self.dropped.set()
            return
        for s in self._subs:
            client.subscribe(s, qos=1)
        if not self._subs:
            self.subscribed.set()
        self.connected.set()

    def _on_subscribe(self, *_a: object) -> None:
        self._subacks += 1
        if self._subacks == len(self._subs):
            self.subscribed.set()

    def _on_message(self, _c: object, _u: object, m: mqtt.MQTTMessage) -> None:
        with self.cond:
            self.got.append((m.topic, bytes(m.payload)))
            self.cond.notify_all()

    def wait_connected(self) -> None:
        """Connected and every subscription acknowledged."""
        wait_for(lambda: self.connected.is_set() or self.dropped.is_set(), 10, what="CONNACK")
        assert self.connected.is_set(), f"connection refused: {self.refused}"
        assert self.subscribed.wait(10), "SUBACK missing"

    def wait_for_topic(self, topic: str, count: int = 1, timeout: float = 20.0) -> list[tuple[str, bytes]]:
        with self.cond:
            ok = self.cond.wait_for(lambda: sum(t == topic for t, _ in self.got) >= count, timeout)
            assert ok, f"{count} x {topic} expected, got {[t for t, _ in self.got][-20:]}"
            return list(self.got)

    def publish(self, topic: str, payload: bytes, qos: int = 1, retain: bool = False) -> None:
        info = self.c.publish(topic, payload, qos=qos, retain=retain)
        if qos:
            info.wait_for_publish(10)
            assert info.is_published(), topic

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


# --------------------------------------------------------------------------------------------------


def test_shipped_config_carries_the_largest_camera_frame_and_refuses_larger_ones() -> None:
    topics = Topics()
    with shipped_broker() as b:
        viewer = Client(b.port, subscribe=(topics.all_camera(),))
        viewer.wait_connected()
        robot = Client(b.port)
        robot.wait_connected()
        try:
            frame = bytes(range(256)) * (MAX_CAMERA_PAYLOAD_BYTES // 256)
            assert len(frame) == MAX_CAMERA_PAYLOAD_BYTES
            robot.c.publish(topics.camera("r1"), frame, qos=0)
            got = viewer.wait_for_topic(topics.camera("r1"))
            assert got[-1][1] == frame

            big = Client(b.port)
            big.wait_connected()
            big.c.publish(topics.camera("r2"), b"x" * (MAX_CAMERA_PAYLOAD_BYTES + 128 * 1024), qos=0)
            assert big.dropped.wait(10), "the broker must drop a client sending an oversized packet"
            big.c.loop_stop()
            robot.c.publish(topics.camera("r1"), b"after", qos=0)
            got = viewer.wait_for_topic(topics.camera("r1"), count=2)
            assert [t for t, _ in got] == [topics.camera("r1")] * 2  # nothing from r2 arrived in between
        finally:
            viewer.close()
            robot.close()


def test_retained_state_and_a_persistent_sessions_queue_survive_a_broker_restart() -> None:
    """What a server restart (persistent session) and a broker restart need: 5000 QoS 1 messages queued
    for an absent subscriber (Mosquitto's default would keep 1000), delivered in order after the broker
    itself restarted, and the retained e-stop still there."""
    topics = Topics()
    n = 5000
    with shipped_broker() as b:
        server = Client(b.port, client_id="fleet-server-test", clean_session=False, subscribe=(topics.all_telemetry(),))
        server.wait_connected()
        server.close()  # away: the broker queues for it from now on
        robot = Client(b.port)
        robot.wait_connected()
        robot.publish(topics.estop(), b'{"engaged": true}', retain=True)
        for seq in range(n):
            robot.c.publish(topics.telemetry("r1", "position"), str(seq).encode(), qos=1)
        robot.publish(topics.telemetry("r1", "imu"), b"last")  # PUBACK of the last: all are queued
        robot.close()

        b.stop()
        b.start()

        server = Client(b.port, client_id="fleet-server-test", clean_session=False)
        try:
            server.wait_connected()
            got = server.wait_for_topic(topics.telemetry("r1", "imu"))
            positions = [int(p) for t, p in got if t == topics.telemetry("r1", "position")]
            assert positions == list(range(n))
        finally:
            server.close()
        late = MqttProbe("127.0.0.1", b.port, [topics.estop()])
        try:
            m = late.wait(lambda m: m.topic == topics.estop())
            assert m.retain and m.payload == b'{"engaged": true}'
        finally:
            late.close()


def _passwd(users: dict[str, str]) -> str:
    path = Path(tempfile.mkdtemp()) / "passwd"
    try:
        path.touch()
        for user, password in users.items():
            subprocess.run(["mosquitto_passwd", "-b", str(path), user, password], check=True, capture_output=True)
        return path.read_text()
    finally:
        shutil.rmtree(path.parent, ignore_errors=True)


def test_acl_example_confines_each_robot_to_its_own_topics() -> None:
    if shutil.which("mosquitto_passwd") is None:
        pytest.fail("mosquitto_passwd missing (Debian package mosquitto)")
    users = {"fleet-server": "pw-server", "snail-1": "pw-1", "snail-2": "pw-2", "legacy": "pw-legacy"}
    files = {"passwd": _passwd(users), "acl": (DEPLOY / "mosquitto" / "acl.example").read_text()}
    with shipped_broker("auth", files) as b:
        anonymous = Client(b.port)
        assert anonymous.dropped.wait(10) and not anonymous.connected.is_set()
        anonymous.c.loop_stop()
        wrong = Client(b.port, username="snail-1", password="nope")
        assert wrong.dropped.wait(10) and not wrong.connected.is_set()
        wrong.c.loop_stop()

        server = Client(
            b.port, username="fleet-server", password="pw-server", subscribe=("fleet/#", "robot/sensor_data/#")
        )
        robot = Client(b.port, username="snail-1", password="pw-1", subscribe=("fleet/#", "robot/#", "+/control/#"))
        legacy = Client(b.port, username="legacy", password="pw-legacy", subscribe=("robot/control/commands",))
        try:
            for c in (server, robot, legacy):
                c.wait_connected()

            # robot -> server: only its own status, telemetry, ack, camera; never another robot's topics,
            # never a command and never the e-stop (a robot must not release the fleet e-stop)
            # (gap repair: it answers on its own repair/reply, and can neither ask as the server nor answer
            # for another robot)
            for topic in (
                "fleet/snail-1/status",
                "fleet/snail-2/status",
                "fleet/snail-1/telemetry/position",
                "fleet/snail-2/telemetry/position",
                "fleet/snail-1/cmd",
                "fleet/snail-2/ack",
                "fleet/estop",
                "robot/sensor_data/position",
                "fleet/snail-1/camera",
                "fleet/snail-1/repair/request",
                "fleet/snail-2/repair/request",
                "fleet/snail-2/repair/reply",
                "fleet/snail-1/repair/reply",
                "fleet/snail-1/ack",
            ):
                robot.publish(topic, b"{}")
            got = [t for t, _ in server.wait_for_topic("fleet/snail-1/ack")]
            assert got == [
                "fleet/snail-1/status",
                "fleet/snail-1/telemetry/position",
                "fleet/snail-1/camera",
                "fleet/snail-1/repair/reply",
                "fleet/snail-1/ack",
            ]

            # server -> robot: the robot reads its own commands, hold and repair requests, the e-stop, the heartbeat
            # and the site only
            for topic in (
                "fleet/snail-2/cmd",
                "fleet/snail-1/status",
                "fleet/snail-1/cmd",
                "fleet/snail-2/hold",
                "fleet/snail-1/hold",
                "fleet/snail-2/repair/request",
                "fleet/snail-1/repair/reply",
                "fleet/snail-1/repair/request",
                "robot/control/commands",
                "snail-1/control/commands",
                "fleet/heartbeat",
                "fleet/site",
                "fleet/estop",
            ):
                server.publish(topic, b"{}")
            got = [t for t, _ in robot.wait_for_topic("fleet/estop")]
            assert got == [
                "fleet/snail-1/cmd",
                "fleet/snail-1/hold",
                "fleet/snail-1/repair/request",
                "fleet/heartbeat",
                "fleet/site",
                "fleet/estop",
            ]
            # a robot can neither fake a server's heartbeat, move the fence, nor release its own hold
            server.wait_for_topic("fleet/estop")
            before = len(server.got)
            for topic in ("fleet/heartbeat", "fleet/site", "fleet/snail-1/hold", "fleet/snail-1/ack"):
                robot.publish(topic, b"{}")
            got = [t for t, _ in server.wait_for_topic("fleet/snail-1/ack", count=2)[before:]]
            assert got == ["fleet/snail-1/ack"]

            # legacy robots keep their old topics
            legacy.publish("robot/sensor_data/position", b'{"robot_id": "old-1", "position": "1,2,0"}')
            server.wait_for_topic("robot/sensor_data/position")
            assert [t for t, _ in legacy.wait_for_topic("robot/control/commands")] == ["robot/control/commands"]
        finally:
            for c in (server, robot, legacy):
                c.close()


def test_legacy_mode_lets_old_framework_robots_in_but_only_on_their_old_topics() -> None:
    """mosquitto.conf's mixed-fleet switch: robots on the old framework cannot send credentials, so anonymous
    clients are allowed, and the ACL's anonymous section keeps them to robot/sensor_data/# and
    robot/control/commands. Accounts still need their password, and nothing under fleet/ is reachable."""
    users = {"fleet-server": "pw-server", "snail-1": "pw-1"}
    files = {"passwd": _passwd(users), "acl": (DEPLOY / "mosquitto" / "acl.example").read_text()}
    with shipped_broker("legacy", files) as b:
        wrong = Client(b.port, username="snail-1", password="nope")
        assert wrong.dropped.wait(10) and not wrong.connected.is_set()
        wrong.c.loop_stop()
        server = Client(
            b.port, username="fleet-server", password="pw-server", subscribe=("fleet/#", "robot/sensor_data/#")
        )
        old = Client(b.port, subscribe=("fleet/#", "robot/control/commands"))  # anonymous, like the seed's
        try:
            for c in (server, old):
                c.wait_connected()
            for topic in (
                "fleet/snail-1/status",
                "fleet/snail-1/telemetry/position",
                "fleet/estop",
                "fleet/snail-1/cmd",
                "robot/sensor_data/position",
            ):
                old.publish(topic, b"{}")
            got = [t for t, _ in server.wait_for_topic("robot/sensor_data/position")]
            assert got == ["robot/sensor_data/position"]
            for topic in ("fleet/snail-1/cmd", "fleet/old/cmd", "robot/control/commands"):
                server.publish(topic, b"{}")
            got = [t for t, _ in old.wait_for_topic("robot/control/commands")]
            assert got == ["robot/control/commands"]
        finally:
            for c in (server, old):
                c.close()


@pytest.mark.parametrize("unit", sorted(p.name for p in (DEPLOY / "systemd").glob("*.service")))
def test_systemd_units_are_valid_and_run_real_commands(unit: str, tmp_path: Path) -> None:
    text = (DEPLOY / "systemd" / unit).read_text()
    (exec_start,) = [ln.split("=", 1)[1] for ln in text.splitlines() if ln.startswith("ExecStart=")]
    argv = exec_start.split()
    if argv[0].startswith("/opt/mollusca-fleet/.venv/bin/"):
        local = [str(VENV_BIN / Path(argv[0]).name), *argv[1:]]
        r = subprocess.run([*local, "--help"], capture_output=True, text=True, timeout=30)
        assert r.returncode == 0, r.stderr
    else:
        assert argv == ["/usr/sbin/mosquitto", "-c", "/etc/mollusca-fleet/mosquitto.conf"]
        local = [_mosquitto(), *argv[1:]]
    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze (Debian package systemd) not installed: unit syntax not checked")
    copy = tmp_path / unit
    copy.write_text(
        text.replace(exec_start, " ".join(local)).replace(
            "EnvironmentFile=/etc/mollusca-fleet/server.env", "EnvironmentFile=/dev/null"
        )
    )
    r = subprocess.run(
        ["systemd-analyze", "verify", str(copy)], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    assert r.returncode == 0 and r.stderr.strip() == "", r.stderr
