"""The shipped ACL (deploy/mosquitto/acl.example) in a real Mosquitto with authentication on, for the safety
topics: the e-stop account writes the fleet e-stop and nothing else; a robot asks the time only on its own
time/req and hears only its own time/resp, which only the server writes. And end to end: `fleet-agent estop`
with that account engages the e-stop of a real simulated agent and a real server with no server involved,
and releases it; a base-station button (mocked GPIO pin) does the same."""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import threading
import time
import zipfile
from pathlib import Path

import orjson
import pytest
from mcap.reader import make_reader

from fleet_protocol import REDACTED, Topics
from tests.deploy.test_mosquitto import DEPLOY, Client, _passwd, shipped_broker
from tests.support.procs import VENV_BIN, AgentProcess, ServerProcess, base_env, wait_for

T = Topics()
USERS = {
    "fleet-server": "pw-server",
    "snail-1": "pw-1",
    "snail-2": "pw-2",
    "legacy": "pw-legacy",
    "fleet-estop": "pw-estop",
}


def _files() -> dict[str, str]:
    return {"passwd": _passwd(USERS), "acl": (DEPLOY / "mosquitto" / "acl.example").read_text()}


def test_estop_account_writes_only_the_estop_and_robots_only_their_own_time_topics() -> None:
    with shipped_broker("auth", _files()) as b:
        server = Client(
            b.port, username="fleet-server", password="pw-server", subscribe=("fleet/#", "robot/sensor_data/#")
        )
        legacy = Client(
            b.port, username="legacy", password="pw-legacy", subscribe=("robot/control/commands", "+/control/commands")
        )
        estop = Client(
            b.port, username="fleet-estop", password="pw-estop", subscribe=("fleet/#", "robot/#", "+/control/#")
        )
        robot = Client(b.port, username="snail-1", password="pw-1", subscribe=("fleet/#",))
        clients = (server, legacy, estop, robot)
        try:
            for c in clients:
                c.wait_connected()

            # the e-stop account: every other kind of topic is dropped, its own "robot namespace" included
            forbidden = [
                "fleet/snail-1/cmd",
                "fleet/snail-1/status",
                "fleet/snail-1/time/resp",
                "fleet/fleet-estop/status",
                "fleet/fleet-estop/telemetry/position",
                "fleet/fleet-estop/ack",
                "fleet/fleet-estop/camera",
                "fleet/fleet-estop/ping",
                "fleet/fleet-estop/time/req",
                "fleet/fleet-estop/config",
                "fleet/other",
                "robot/control/commands",
                "snail-1/control/commands",
                "robot/sensor_data/position",
            ]
            for topic in forbidden:
                estop.publish(topic, b"{}")
            estop.publish("fleet/estop", b'{"ts": 1, "engaged": false}')  # allowed: the marker
            got = [t for t, _ in server.wait_for_topic("fleet/estop")]
            assert got == ["fleet/estop"], got
            server.publish("robot/control/commands", b"stop")  # after the e-stop account's attempts
            assert [t for t, _ in legacy.wait_for_topic("robot/control/commands")] == ["robot/control/commands"]
            # ... and it reads nothing but the e-stop
            for topic in ("fleet/snail-1/cmd", "fleet/snail-1/status", "fleet/snail-1/time/resp", "fleet/estop"):
                server.publish(topic, b"{}")
            assert [t for t, _ in estop.wait_for_topic("fleet/estop", count=2)] == ["fleet/estop"] * 2

            # time sync: a robot asks on its own req only and cannot forge answers (first let the messages
            # above arrive everywhere: the second fleet/estop is the last of them on each connection)
            server.wait_for_topic("fleet/estop", count=2)
            robot.wait_for_topic("fleet/estop", count=2)
            seen = len(server.got)
            for topic in (
                "fleet/snail-2/time/req",
                "fleet/snail-1/time/resp",
                "fleet/snail-2/time/resp",
                "fleet/snail-1/time/req",
            ):
                robot.publish(topic, b'{"t0": 1}')
            got = [t for t, _ in server.wait_for_topic("fleet/snail-1/time/req")][seen:]
            assert got == ["fleet/snail-1/time/req"], got
            # the server answers; a robot hears only its own answer
            seen = len(robot.got)
            for topic in ("fleet/snail-2/time/resp", "fleet/snail-2/time/req", "fleet/snail-1/time/resp"):
                server.publish(topic, b'{"t0": 1, "t1": 2, "t2": 3}')
            got = [t for t, _ in robot.wait_for_topic("fleet/snail-1/time/resp", count=2)]  # the earlier one + this
            assert got[seen:] == ["fleet/snail-1/time/resp"], got  # not snail-2's
            assert (T.time_resp("snail-1"), b'{"t0": 1}') not in robot.got  # its own forged answer never arrived
        finally:
            for c in clients:
                c.close()


class _PlainBroker:
    """What AgentProcess / ServerProcess need of a broker (the server's URL carries its credentials)."""

    def __init__(self, port: int, url: str) -> None:
        self.host, self.port, self.url = "127.0.0.1", port, url


def _estop_cli(port: int, *args: str, password: str = "pw-estop") -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(VENV_BIN / "fleet-agent"), "estop", "--broker", f"mqtt://127.0.0.1:{port}", *args],
        env=base_env(FLEET_ESTOP_PASSWORD=password),
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_fleet_agent_estop_stops_a_real_agent_and_shows_in_the_server_without_the_server(tmp_path: Path) -> None:
    with shipped_broker("auth", _files()) as b:
        server = ServerProcess(
            _PlainBroker(b.port, f"mqtt://fleet-server:pw-server@127.0.0.1:{b.port}"),  # type: ignore[arg-type]
            f"sqlite:///{tmp_path / 'fleet.db'}",
            tmp_path,
        )
        trace = tmp_path / "motors.jsonl"
        agent = AgentProcess(
            "snail-1",
            _PlainBroker(b.port, f"mqtt://127.0.0.1:{b.port}"),
            tmp_path,  # type: ignore[arg-type]
            ["--start-pose", "0,0,0"],
            FLEET_AGENT_PASSWORD="pw-1",
            FLEET_AGENT_MOTORS=orjson.dumps({"type": "sim", "trace_file": str(trace)}).decode(),
        )
        probe = Client(
            b.port,
            username="fleet-server",
            password="pw-server",
            subscribe=("fleet/snail-1/status", "fleet/snail-1/ack"),
        )
        try:
            server.start()
            agent.start()
            probe.wait_connected()
            # the robot syncs its clock through the ACL: its req reaches the server, the answer reaches it
            probe.wait_for_topic("fleet/snail-1/status")
            wait_for(
                lambda: any(
                    orjson.loads(p).get("clock_synced") for t, p in list(probe.got) if t == "fleet/snail-1/status"
                ),
                20,
                what="clock synced under the ACL",
            )
            with server.client() as c:
                wait_for(
                    lambda: (
                        c.get("/api/robots/snail-1").status_code == 200
                        and c.get("/api/robots/snail-1").json()["online"]
                    ),
                    20,
                )
                # a robot's account cannot engage (or release) it: the confirmation catches the dropped publish
                robot_try = _estop_cli(b.port, "--username", "snail-1", "--timeout", "2", password="pw-1")
                assert robot_try.returncode == 1 and "NOT engaged" in robot_try.stderr, robot_try.stderr
                wrong = _estop_cli(b.port, password="wrong")
                assert wrong.returncode == 1 and "refused" in wrong.stderr, wrong.stderr
                assert c.get("/api/estop").json()["engaged"] is False

                r = c.post(
                    "/api/robots/snail-1/commands",
                    json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 5.0}},
                )
                assert r.status_code == 202, r.text
                cid = r.json()["id"]
                wait_for(lambda: trace.exists() and trace.read_text().count("\n") == 1, 10, what="driving")

                started = time.time()
                done = _estop_cli(b.port, "--reason", "pool wall")
                assert done.returncode == 0, done.stderr
                assert "ENGAGED" in done.stdout
                state = wait_for(lambda: (s := c.get("/api/estop").json())["acks"].get("snail-1") == "done" and s, 10)
                assert state["engaged"] is True and state["reason"] == "pool wall"
                wait_for(lambda: c.get(f"/api/commands/{cid}").json()["status"] == "done", 10)
                on, off, *rest = [orjson.loads(line) for line in trace.read_text().splitlines()]
                assert on["left"] == 1.0 and off["left"] == 0.0 and all(r["left"] == 0.0 for r in rest)
                # stopped by the e-stop: after it was sent (its ts is taken by the tool once started: a loaded machine
                # takes seconds to start the tool itself) and seconds before the drive's own end
                assert started <= state["ts"] <= off["t"] < state["ts"] + 2.0, (started, state["ts"], off["t"])
                assert off["t"] < on["t"] + 5.0 - 2.0

                released = _estop_cli(b.port, "--release", "--reason", "clear")
                assert released.returncode == 0, released.stderr
                wait_for(lambda: c.get("/api/estop").json()["engaged"] is False, 10)
                r = c.post(
                    "/api/robots/snail-1/commands?wait=5", json={"command": "move_forward", "args": {"duration_s": 0.2}}
                )
                assert r.json()["status"] == "done", r.text
        finally:
            probe.close()
            agent.stop()
            server.stop()
        assert "pw-estop" not in agent.output() + server.output()


def test_base_station_button_engages_the_estop(tmp_path: Path) -> None:
    gpiozero = pytest.importorskip("gpiozero")
    from gpiozero.pins.mock import MockFactory

    from robot_agent.estop_cli import _engager, run_button

    with shipped_broker("auth", _files()) as b:
        watch = Client(b.port, username="fleet-server", password="pw-server", subscribe=("fleet/estop",))
        factory = MockFactory()
        gpiozero.Device.pin_factory = factory
        stop = threading.Event()
        secret = tmp_path / "estop-password"
        secret.write_text("pw-estop\n")
        try:
            watch.wait_connected()
            args = argparse.Namespace(
                broker=f"mqtt://127.0.0.1:{b.port}",
                username="fleet-estop",
                password_file=secret,
                tls_ca=None,
                prefix="fleet",
                timeout=5.0,
            )
            send = _engager(args)
            button = gpiozero.Button(17, pull_up=True, bounce_time=None)
            worker = threading.Thread(
                target=run_button, args=(button, lambda: send(True, "button", "button@test"), stop)
            )
            worker.start()
            assert watch.got == []
            factory.pin(17).drive_low()  # pressed (to ground)
            got = watch.wait_for_topic("fleet/estop")
            msg = orjson.loads(got[-1][1])
            assert msg["engaged"] is True and msg["source"] == "button@test"
        finally:
            stop.set()
            worker.join(5)
            watch.close()
            factory.reset()
            gpiozero.Device.pin_factory = None


def test_no_robot_can_get_the_estop_account(tmp_path: Path) -> None:
    """`fleet-server robots add fleet-estop` is refused: that account may only write the e-stop, and a robot
    under that name would be silenced by the ACL's deny line."""
    out = subprocess.run(
        [str(VENV_BIN / "fleet-server"), "robots", "add", "fleet-estop", "--password-file", str(tmp_path / "passwd")],
        env=base_env(),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1 and "reserved" in out.stderr, out.stderr
    assert not (tmp_path / "passwd").exists()


def test_an_agent_publishes_its_config_without_secrets_only_on_its_own_topic_and_a_run_records_it(
    tmp_path: Path,
) -> None:
    """A real agent with a broker password, under the shipped ACL: its effective configuration arrives
    retained on its own config topic with the password redacted; its account cannot write another robot's
    config; a run records the config (API, MCAP metadata, run.json) and the password appears nowhere."""
    with shipped_broker("auth", _files()) as b:
        server = ServerProcess(
            _PlainBroker(b.port, f"mqtt://fleet-server:pw-server@127.0.0.1:{b.port}"),  # type: ignore[arg-type]
            f"sqlite:///{tmp_path / 'fleet.db'}",
            tmp_path,
        )
        agent = AgentProcess(
            "snail-1",
            _PlainBroker(b.port, f"mqtt://127.0.0.1:{b.port}"),  # type: ignore[arg-type]
            tmp_path,
            ["--start-pose", "0,0,0", "--position-rate", "7"],
            FLEET_AGENT_PASSWORD="pw-1",
        )
        probe = Client(b.port, username="fleet-server", password="pw-server", subscribe=("fleet/+/config",))
        forger = Client(b.port, username="snail-1", password="pw-1")
        try:
            server.start()
            agent.start()
            probe.wait_connected()
            forger.wait_connected()
            got = probe.wait_for_topic(T.config("snail-1"))
            msg = orjson.loads(got[-1][1])
            config = msg["config"]
            assert config["robot_id"] == "snail-1" and config["username"] == "snail-1"
            assert config["password"] == REDACTED and config["position_rate"] == 7.0
            assert msg["agent_version"] and msg["protocol_version"] == 1 and msg["boot"]
            assert b"pw-1" not in got[-1][1]

            # the robot's account writes only its own config: another robot's is dropped by the ACL, its own
            # (written after it, on the same connection) arrives, so the other one could have arrived first
            forger.publish(T.config("snail-2"), b'{"ts": 1, "config": {"forged": true}}', retain=True)
            forger.publish(T.config("snail-1"), got[-1][1], retain=True)
            seen = probe.wait_for_topic(T.config("snail-1"), count=2)
            assert [t for t, _ in seen] == [T.config("snail-1")] * 2
            late = Client(b.port, username="fleet-server", password="pw-server", subscribe=("fleet/+/config",))
            try:
                late.wait_connected()
                assert [t for t, _ in late.wait_for_topic(T.config("snail-1"))] == [T.config("snail-1")]
            finally:
                late.close()

            with server.client() as c:
                wait_for(lambda: c.get("/api/robots/snail-1").status_code == 200, 20, what="snail-1 known")
                wait_for(lambda: c.get("/api/robots/snail-1").json()["online"], 20, what="snail-1 online")
                r = c.post("/api/runs", json={"name": "config trial", "robots": ["snail-1"]})
                assert r.status_code == 201, r.text
                run_id = r.json()["id"]
                # the config reached the server with the status; a run started first gets it when it comes
                wait_for(
                    lambda: c.get(f"/api/runs/{run_id}").json()["agents"]["snail-1"]["config"] is not None,
                    20,
                    what="the run recorded the agent's config",
                )
                assert c.post(f"/api/runs/{run_id}/stop").status_code == 200
                agent_info = c.get(f"/api/runs/{run_id}").json()["agents"]["snail-1"]
                assert agent_info["config"]["robot_id"] == "snail-1" and agent_info["config"]["password"] == REDACTED
                assert agent_info["boot"] == msg["boot"] and agent_info["agent_version"] == msg["agent_version"]
                mcap = c.get(f"/api/runs/{run_id}/export", params={"format": "mcap"}).content
                meta = {m.name: m.metadata for m in make_reader(io.BytesIO(mcap)).iter_metadata()}
                assert meta["agent/snail-1"]["config.robot_id"] == "snail-1"
                assert meta["agent/snail-1"]["config.password"] == REDACTED
                bundle = c.get(f"/api/runs/{run_id}/export", params={"format": "zip"}).content
                run_json = json.loads(zipfile.ZipFile(io.BytesIO(bundle)).read("run.json"))
                assert run_json["run"]["agents"]["snail-1"]["config"]["position_rate"] == 7.0
                assert b"pw-1" not in mcap and b"pw-1" not in bundle
        finally:
            probe.close()
            forger.close()
            agent.stop()
            server.stop()
        assert "pw-1" not in server.output()


def test_every_robot_reads_the_fleet_poses_and_only_the_server_writes_them() -> None:
    """The poses are what each robot's safety filter keeps clear of: a robot that could write them could hide a
    neighbour from the fleet, or put a phantom in its way."""
    with shipped_broker("auth", _files()) as b:
        server = Client(b.port, username="fleet-server", password="pw-server", subscribe=(T.poses(),))
        robot = Client(b.port, username="snail-1", password="pw-1", subscribe=(T.poses(),))
        other = Client(b.port, username="snail-2", password="pw-2", subscribe=(T.poses(),))
        clients = (server, robot, other)
        try:
            for c in clients:
                c.wait_connected()
            robot.publish(T.poses(), b'{"server_id": "forged", "ts": 1, "seq": 0, "robots": []}')
            server.publish(T.poses(), b'{"server_id": "fleet-server", "ts": 2, "seq": 0, "robots": []}')
            for c in clients:  # the server's reaches every robot (and itself); the robot's forgery reaches nobody
                got = c.wait_for_topic(T.poses())
                assert [p for t, p in got if t == T.poses()] == [
                    b'{"server_id": "fleet-server", "ts": 2, "seq": 0, "robots": []}'
                ]
        finally:
            for c in clients:
                c.close()
