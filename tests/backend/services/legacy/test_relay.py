"""Robots on the old framework get their safety from the server (they have no deadman or e-stop of their
own). Measured on a client that behaves exactly like the seed's robot, through the shipped Mosquitto
config with its ACL on (legacy mode: anonymous old-framework robots, the server with its account)."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from tests.backend.helpers import register_legacy, wait_robot
from tests.deploy.test_mosquitto import DEPLOY, ShippedBroker, _passwd, shipped_broker
from tests.support.procs import VENV_BIN, ManagedProcess, ServerProcess, base_env, wait_for
from tests.support.proxy import FreezableProxy
from tests.support.seed_robot import SeedRobot

pytestmark = pytest.mark.realtime  # wall-clock safety bounds: the realtime lane, alone (docs/testing.md)

SERVER_PASSWORD = "pw-server-legacy-safety"


@pytest.fixture
def acl_broker() -> Iterator[ShippedBroker]:
    files = {
        "passwd": _passwd({"fleet-server": SERVER_PASSWORD}),
        "acl": (DEPLOY / "mosquitto" / "acl.example").read_text(),
    }
    with shipped_broker("legacy", files) as b:
        yield b


def _url(port: int) -> Any:
    return SimpleNamespace(url=f"mqtt://127.0.0.1:{port}")


def _server(port: int, database_url: str, workdir: Path, **env: str) -> ServerProcess:
    s = ServerProcess(_url(port), database_url, workdir, FLEET_MQTT_PASSWORD=SERVER_PASSWORD, **env)
    s.start()
    return s


@pytest.fixture
def legacy_server(acl_broker: ShippedBroker, database_url: str, workdir: Path) -> Iterator[ServerProcess]:
    s = _server(acl_broker.port, database_url, workdir)
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture
def seed_robots(acl_broker: ShippedBroker) -> Iterator[Any]:
    robots: list[SeedRobot] = []

    def make(robot_id: str, own_topic: bool = False) -> SeedRobot:
        r = SeedRobot("127.0.0.1", acl_broker.port, robot_id, own_topic)
        robots.append(r)
        return r

    try:
        yield make
    finally:
        for r in robots:
            r.close()


def _online(server: ServerProcess, robot: SeedRobot) -> None:
    with server.client() as c:
        register_legacy(c, robot.robot_id)
        robot.publish_position()
        wait_robot(c, robot.robot_id, lambda r: r["online"] and r["legacy"])


def _drive(c: Any, robot_id: str, duration_s: float = 0.5, command: str = "move_forward") -> Any:
    return c.post(f"/api/robots/{robot_id}/commands", json={"command": command, "args": {"duration_s": duration_s}})


def test_fleet_estop_stops_a_seed_robot_and_no_drive_reaches_it_while_latched(legacy_server, seed_robots):
    robot = seed_robots("old-1")
    _online(legacy_server, robot)
    with legacy_server.client() as c:
        t0 = time.time()
        assert _drive(c, "old-1", duration_s=5).status_code == 202
        drive = robot.wait_heard("move_forward", t0)
        assert drive.qos == 0  # a drive queued for a reconnecting robot must never run late
        assert robot.driving == "move_forward"  # it could move: now the e-stop must stop it

        engaged_at = time.time()
        r = c.post("/api/estop", json={"reason": "swimmer in the pool", "source": "test"})
        assert r.status_code == 202
        stop = robot.wait_heard("stop", engaged_at, timeout=5)
        assert stop.at - engaged_at <= 0.3, stop.at - engaged_at
        assert robot.driving is None

        # while latched: the server refuses drives (409 naming the e-stop) and forwards none
        refused = _drive(c, "old-1")
        assert refused.status_code == 409, refused.text
        assert "e-stop" in refused.json()["detail"] and "swimmer in the pool" in refused.json()["detail"]
        assert "by FLEET_ADMIN_TOKEN via test" in refused.json()["detail"]  # who engaged it, and from where
        assert c.post("/api/robots/old-1/commands", json={"command": "stop"}).status_code == 202  # stop passes
        # "stop" again every second while latched
        wait_for(
            lambda: len([h for h in robot.commands(engaged_at) if h.command == "stop"]) >= 4, 5, what="e-stop beacons"
        )
        beacons = [h.at for h in robot.commands(engaged_at) if h.command == "stop"]
        assert beacons[-1] - beacons[0] >= 1.5

        # a legacy robot that appears while latched hears "stop" at once (not only at the next beacon)
        late = seed_robots("old-late", own_topic=True)
        register_legacy(c, "old-late")
        appeared = time.time()
        late.publish_position()
        heard = late.wait_heard("stop", appeared, timeout=5)
        assert heard.at - appeared <= 0.3, heard.at - appeared
        assert heard.topic == "old-late/control/commands"

        assert c.post("/api/estop/release", json={"source": "test"}).status_code == 202
        assert [h.command for h in robot.commands(engaged_at) if h.command != "stop"] == []
        released = time.time()
        assert _drive(c, "old-1").status_code == 202
        robot.wait_heard("move_forward", released)


def test_a_lone_drive_is_followed_by_stop_and_renewals_keep_it_going(legacy_server, seed_robots):
    robot = seed_robots("old-2")
    _online(legacy_server, robot)
    with legacy_server.client() as c:
        # renewed every 0.2 s with a 0.5 s deadman: it keeps driving, no stop in between
        t0 = time.time()
        for _ in range(6):
            assert _drive(c, "old-2", duration_s=0.5).status_code == 202
            last = time.time()
            time.sleep(0.2)  # the renewal period a client uses (the behaviour under test, not a wait)
        stop = robot.wait_heard("stop", t0, timeout=5)
        assert stop.at >= last, "stopped while still renewed"
        assert stop.at - last <= 0.5 + 0.3, stop.at - last

        # a lone drive that is never renewed (a browser died mid-hold)
        lone_at = time.time()
        assert _drive(c, "old-2", duration_s=0.5).status_code == 202
        robot.wait_heard("move_forward", lone_at)
        stop = robot.wait_heard("stop", lone_at, timeout=5)
        assert 0.4 <= stop.at - lone_at <= 0.5 + 0.3, stop.at - lone_at


def test_a_drive_goes_only_to_the_topics_its_target_listens_on(legacy_server, seed_robots):
    shared = seed_robots("old-shared")  # the seed's code: robot/control/commands
    own = seed_robots("old-own", own_topic=True)
    _online(legacy_server, shared)
    _online(legacy_server, own)
    with legacy_server.client() as c:
        r = c.put("/api/robots/old-own/legacy-addressing", json={"listens_on": "own"})
        assert r.status_code == 200, r.text
        assert r.json()["legacy_listens_on"] == "own" and r.json()["legacy_unit"] == ["old-own"]
        assert c.get("/api/robots/old-shared").json()["legacy_unit"] == ["old-shared"]
        assert c.put("/api/robots/old-own/legacy-addressing", json={"listens_on": "x"}).status_code == 422

        t0 = time.time()
        assert _drive(c, "old-own").status_code == 202
        own.wait_heard("move_forward", t0)
        assert _drive(c, "old-shared", command="turn_left").status_code == 202
        shared.wait_heard("turn_left", t0)
        own.wait_heard("stop", t0)  # both deadmen lapse, so everything both heard is in by now
        shared.wait_heard("stop", t0)
        assert "move_forward" not in [h.command for h in shared.commands(t0)]
        assert "turn_left" not in [h.command for h in own.commands(t0)]


def test_hold_stops_a_seed_robot_and_refuses_drives_to_its_whole_unit(legacy_server, seed_robots):
    a, b = seed_robots("old-a"), seed_robots("old-b")  # both on the shared topic: one unit
    _online(legacy_server, a)
    _online(legacy_server, b)
    with legacy_server.client() as c:
        assert c.get("/api/robots/old-a").json()["legacy_unit"] == ["old-a", "old-b"]
        t0 = time.time()
        assert _drive(c, "old-a", duration_s=5).status_code == 202
        b.wait_heard("move_forward", t0)  # one drive moves them all: that is why they are one unit
        held_at = time.time()
        r = c.put("/api/robots/old-a/hold", json={"reason": "tangled"})
        assert r.status_code == 200 and r.json()["held"] is True
        assert a.wait_heard("stop", held_at).at - held_at <= 0.3
        for rid in ("old-a", "old-b"):
            refused = _drive(c, rid)
            assert refused.status_code == 409 and "held" in refused.json()["detail"], refused.text
        assert c.get("/api/robots/old-a").json()["hold"]["reason"] == "tangled"
        assert c.delete("/api/robots/old-a/hold").status_code == 200
        assert c.get("/api/robots/old-a").json()["hold"] is None
        assert _drive(c, "old-b").status_code == 202


@pytest.mark.parametrize("how", ["kill", "sigterm"])
def test_a_seed_robot_stops_when_the_server_dies_or_shuts_down(acl_broker, database_url, workdir, seed_robots, how):
    server = _server(acl_broker.port, database_url, workdir)
    try:
        robot = seed_robots("old-3")
        _online(server, robot)
        with server.client() as c:
            t0 = time.time()
            assert _drive(c, "old-3", duration_s=5).status_code == 202
            robot.wait_heard("move_forward", t0)
        gone_at = time.time()
        assert server.proc is not None
        if how == "kill":
            server.proc.send_signal(signal.SIGKILL)  # its Last Will speaks for it
        else:
            server.proc.send_signal(signal.SIGTERM)  # a clean DISCONNECT: no Will, the server says it
        stop = robot.wait_heard("stop", gone_at, timeout=5)
        assert stop.at - gone_at <= 2.0, stop.at - gone_at
        assert robot.driving is None
    finally:
        server.stop()


def test_a_seed_robot_stops_when_the_server_is_cut_off_from_the_broker(acl_broker, database_url, workdir, seed_robots):
    """A partition: the server's link to the broker frozen (no FIN, no RST). The broker's own keepalive
    check takes seconds; the sentinel beside the broker hears the heartbeat stop and stops the robots."""
    proxy = FreezableProxy("127.0.0.1", acl_broker.port)
    sentinel = ManagedProcess(
        "sentinel",
        [str(VENV_BIN / "fleet-server"), "legacy-sentinel"],
        base_env(FLEET_MQTT_URL=f"mqtt://127.0.0.1:{acl_broker.port}", FLEET_MQTT_PASSWORD=SERVER_PASSWORD),
        workdir,
    )
    sentinel.start()
    server = _server(proxy.port, database_url, workdir)
    try:
        wait_for(
            lambda: "server" in sentinel.output() and "heard" in sentinel.output(),
            10,
            what="the sentinel hears the server's heartbeat",
        )
        robot = seed_robots("old-4")
        _online(server, robot)
        with server.client() as c:
            t0 = time.time()
            assert _drive(c, "old-4", duration_s=5).status_code == 202
            robot.wait_heard("move_forward", t0)
        cut_at = time.time()
        proxy.frozen.set()
        stop = robot.wait_heard("stop", cut_at, timeout=5)
        assert stop.at - cut_at <= 2.0, stop.at - cut_at
        assert "silent" in sentinel.output()
    finally:
        proxy.frozen.clear()
        server.stop()
        assert sentinel.stop() is not None
        proxy.close()
