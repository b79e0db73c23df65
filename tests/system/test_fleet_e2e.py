"""The whole spine with every part real: Mosquitto, ``fleet-server`` and simulated ``fleet-agent`` processes.

These tests drive robots only through the server's REST API, as a researcher's script would, and check the
safety rules of the foundation issue end to end: drives stop after ``duration_s``, stale commands never run,
e-stop stops everyone, a dead robot is marked offline by its Last Will and refuses commands.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import signal
import time
from collections.abc import Iterator
from typing import Any

import httpx

from tests.backend.helpers import wait_robot
from tests.support.procs import wait_for

ROBOTS = {"snail-1": "-1,-1,0", "snail-2": "0,0,1.57", "snail-3": "1,1,3.14"}


def _pos(c: httpx.Client, robot_id: str) -> dict[str, Any]:
    return c.get(f"/api/robots/{robot_id}").json()["position"]  # type: ignore[no-any-return]


def _dist(a: dict[str, Any], b: dict[str, Any]) -> float:
    return math.hypot(a["x"] - b["x"], a["y"] - b["y"])


def _settled(c: httpx.Client, robot_id: str, window_s: float = 0.5) -> dict[str, Any]:
    """The robot's position once it has not moved for ``window_s`` (new telemetry keeps arriving)."""
    last = _pos(c, robot_id)

    def still() -> dict[str, Any] | None:
        nonlocal last
        time.sleep(window_s)  # the stillness window is the definition of "settled", not a wait for an event
        now = _pos(c, robot_id)
        moved = _dist(now, last) > 1e-4 or now["ts"] <= last["ts"]
        last = now
        return None if moved else now

    return wait_for(still, 10, what=f"{robot_id} standing still")  # type: ignore[no-any-return]


@contextlib.contextmanager
def _start_fleet(server, spawn_agent, *extra: str) -> Iterator[tuple[httpx.Client, dict[str, Any]]]:
    agents = {rid: spawn_agent(rid, f"--start-pose={pose}", *extra) for rid, pose in ROBOTS.items()}
    with server.client() as c:
        for rid in ROBOTS:
            wait_robot(c, rid, lambda r: r["online"] and r["position"] is not None, timeout=30)
        yield c, agents


def test_drive_runs_for_its_duration_then_stops(server, spawn_agent):
    with _start_fleet(server, spawn_agent) as (c, _agents):
        start = _settled(c, "snail-2")
        r = c.post(
            "/api/robots/snail-2/commands?wait=5",
            json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 1.0}},
        )
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["status"] == "done", body
        assert [a["status"] for a in body["acks"]] == ["accepted", "done"]
        end = _settled(c, "snail-2")
        # max speed 0.3 m/s for 1 s, heading +y (yaw 1.57): about 0.3 m, nothing more after `done`
        assert 0.25 < _dist(start, end) < 0.35, (start, end)
        assert abs(end["x"] - start["x"]) < 0.02 and end["y"] > start["y"]
        # the others never moved
        assert _dist(_pos(c, "snail-1"), {"x": -1, "y": -1}) < 1e-3


def test_stale_command_is_acked_expired_and_never_executed(server, spawn_agent):
    with _start_fleet(server, spawn_agent) as (c, agents):
        agent_pid = agents["snail-1"].proc.pid
        start = _settled(c, "snail-1")
        os.kill(agent_pid, signal.SIGSTOP)  # the robot's link stalls (e.g. Wi-Fi hiccup) ...
        try:
            r = c.post(
                "/api/robots/snail-1/commands",
                json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 2.0}, "ttl_s": 0.5},
            )
            assert r.status_code == 202, r.text
            cid = r.json()["id"]
            time.sleep(1.5)  # ... longer than the command's ttl: the stall's length is the scenario under test
        finally:
            os.kill(agent_pid, signal.SIGCONT)
        cmd = wait_for(lambda: (x := c.get(f"/api/commands/{cid}").json())["status"] != "sent" and x, 10, what="ack")
        assert cmd["status"] == "expired", cmd
        assert [a["status"] for a in cmd["acks"]] == ["expired"]
        # the agent has handled the command (its ack says so): a drive would have started by now, and
        # _settled waits until the robot stands still before it is measured
        assert _dist(_settled(c, "snail-1"), start) < 1e-3


def _rejected_by_the_robot_itself(mqtt_probe, robot_id: str) -> dict[str, Any]:
    """A drive published straight on the robot's command topic (past the server, which refuses it with 409
    while the e-stop is latched): the robot's own latch refuses it too."""
    from fleet_protocol import Topics, dumps, new_command

    topics = Topics()
    acks = mqtt_probe(topics.ack(robot_id))
    cmd = new_command("move_forward", {"speed": 0.5, "duration_s": 1.0})
    acks.publish(topics.cmd(robot_id), dumps(cmd), qos=1)
    msg = acks.wait(lambda m: m.json()["id"] == cmd.id)  # type: ignore[index]
    return msg.json()  # type: ignore[return-value]


def test_estop_stops_every_robot_and_latches_until_release(server, spawn_agent, mqtt_probe):
    with _start_fleet(server, spawn_agent) as (c, agents):
        starts = {rid: _settled(c, rid) for rid in ROBOTS}
        ids = []
        for rid in ROBOTS:  # no ?wait: it would wait for the final ack, 5 s from now
            r = c.post(
                f"/api/robots/{rid}/commands",
                json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 5.0}},
            )
            assert r.status_code == 202, r.text
            ids.append(r.json()["id"])
        for cid in ids:
            wait_for(lambda cid=cid: c.get(f"/api/commands/{cid}").json()["status"] == "accepted", 5, what="accepted")
        wait_for(lambda: all(_dist(_pos(c, rid), starts[rid]) > 0.02 for rid in ROBOTS), 5, what="every robot moving")
        r = c.post("/api/estop", json={"reason": "test", "source": "pytest"})
        assert r.status_code in (200, 202), r.text

        def all_acked() -> dict[str, Any] | None:
            state = c.get("/api/estop").json()
            acks = state.get("acks", {})
            return state if state["engaged"] and all(rid in acks for rid in ROBOTS) else None

        wait_for(all_acked, 5, what="every robot acks the e-stop")
        stopped = {rid: _settled(c, rid) for rid in ROBOTS}
        for rid in ROBOTS:
            travelled = _dist(starts[rid], stopped[rid])
            assert 0.02 < travelled < 0.5, (rid, travelled)  # moved, then stopped well before 5 s of drive
            assert c.get(f"/api/robots/{rid}").json()["estop"] is True
        # latched: a new drive is refused by the server (409) and, sent past it, by the robot itself
        r = c.post("/api/robots/snail-3/commands?wait=3", json={"command": "move_forward", "args": {"duration_s": 1.0}})
        assert r.status_code == 409 and "e-stop engaged" in r.json()["detail"], r.text
        ack = _rejected_by_the_robot_itself(mqtt_probe, "snail-3")
        assert ack["status"] == "rejected" and "e-stop" in ack["reason"].lower(), ack
        # the robot has handled the drive (it refused it): positions it reports for half a second after
        # that would show a drive that started anyway
        refused_at = time.time()
        wait_for(lambda: _pos(c, "snail-3")["ts"] > refused_at + 0.5, 5, what="positions after the refusal")
        assert _dist(_pos(c, "snail-3"), stopped["snail-3"]) < 1e-3
        # ... and after a reboot: the retained e-stop reaches the new agent before it takes any command
        agents["snail-2"].stop()
        wait_robot(c, "snail-2", lambda r: not r["online"], timeout=10)
        spawn_agent("snail-2", f"--start-pose={ROBOTS['snail-2']}")
        wait_robot(c, "snail-2", lambda r: r["online"] and r["estop"] is True, timeout=30)
        assert _rejected_by_the_robot_itself(mqtt_probe, "snail-2")["status"] == "rejected"

        assert c.post("/api/estop/release", json={"source": "pytest"}).status_code in (200, 202)
        wait_for(lambda: not c.get("/api/robots/snail-3").json()["estop"], 5, what="release reaches robot")
        r = c.post(
            "/api/robots/snail-3/commands?wait=3",
            json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 0.5}},
        )
        assert r.json()["status"] == "done", r.text
        assert _dist(_settled(c, "snail-3"), stopped["snail-3"]) > 0.05


def test_killed_robot_goes_offline_by_last_will_and_refuses_commands(server, spawn_agent):
    agent = spawn_agent("snail-9", "--keepalive", "2")
    with server.client() as c:
        wait_robot(c, "snail-9", lambda r: r["online"] and r["position"] is not None, timeout=30)
        agent.kill()  # SIGKILL: no clean shutdown, only the broker's Last Will can tell
        # the broker gives up after 1.5 x keepalive (3 s); allow scheduling slack on a loaded machine
        wait_robot(c, "snail-9", lambda r: not r["online"], timeout=3 + 5)
        r = c.post("/api/robots/snail-9/commands", json={"command": "move_forward"})
        assert r.status_code == 409, r.text
        assert "offline" in r.json()["detail"].lower()


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_todays_sensor_modules_feed_the_agent_over_udp_into_the_server(server, spawn_agent, workdir):
    """An unchanged Lighthouse module (UDP 5006 format) and IMU module (5005) -> agent -> broker -> server."""
    import socket

    pos_port, imu_port, tag_port = _free_udp_port(), _free_udp_port(), _free_udp_port()
    cfg = workdir / "legacy-agent.toml"
    cfg.write_text(
        f"[legacy_udp]\nimu_port = {imu_port}\nposition_port = {pos_port}\napriltag_port = {tag_port}\n"
        '[[sensors]]\ntype = "position"\nsource = "legacy"\n'
        '[[sensors]]\ntype = "imu"\nsource = "legacy"\n'
    )
    spawn_agent("udp-1", "--config", str(cfg))
    with server.client() as c:
        wait_robot(c, "udp-1", lambda r: r["online"] and "position" in r["capabilities"]["sensors"], timeout=30)

        def pump() -> dict[str, Any] | None:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(b"[0.5 -1.25 0.1]", ("127.0.0.1", pos_port))  # numpy's print format
                s.sendto(b"0.1,0.2,9.81,0,0,0.3", ("127.0.0.1", imu_port))
            r = c.get("/api/robots/udp-1").json()
            return r if r["position"] else None

        robot = wait_for(pump, 10, interval=0.2, what="legacy position reaches the server")
        assert (robot["position"]["x"], robot["position"]["y"], robot["position"]["z"]) == (0.5, -1.25, 0.1)
        assert robot["legacy"] is False  # a new agent, fed by old modules
        imu = wait_for(
            lambda: c.get("/api/robots/udp-1/telemetry", params={"stream": "imu"}).json()["points"],
            5,
            what="stored imu",
        )
        assert imu[-1]["data"] == {"accel": [0.1, 0.2, 9.81], "gyro": [0.0, 0.0, 0.3]}


def test_cut_link_shows_the_robot_offline_within_1_5_keepalive_and_stops_it(server, workdir):
    """A Wi-Fi dropout (the TCP link frozen both ways, nothing closed): the agent's watchdog stops the motors
    within 0.5 s; the server shows the robot offline 1.5 x keepalive after its last message (Mosquitto's
    own keepalive check can take seconds longer); when the link comes back the robot is online again."""
    from tests.support.procs import VENV_BIN, ManagedProcess, base_env
    from tests.support.proxy import FreezableProxy

    proxy = FreezableProxy(server.broker.host, server.broker.port)
    keepalive = 2
    agent = ManagedProcess(
        "agent-lk-1",
        [
            str(VENV_BIN / "fleet-agent"),
            "--robot-id",
            "lk-1",
            "--simulate",
            "--broker",
            proxy.url,
            "--keepalive",
            str(keepalive),
            "--start-pose=0,0,0",
        ],
        base_env(),
        workdir,
    )
    agent.start()
    try:
        with server.client() as c:
            wait_robot(c, "lk-1", lambda r: r["online"] and r["position"] is not None, timeout=30)
            r = c.post(
                "/api/robots/lk-1/commands?wait=2",
                json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 5.0}},
            )
            assert r.status_code == 200 and r.json()["status"] == "accepted", r.text
            before = c.get("/api/robots/lk-1").json()["position"]
            wait_for(
                lambda: _dist(c.get("/api/robots/lk-1").json()["position"], before) > 0.01,
                5,
                what="the robot driving before the link freezes",
            )
            frozen_at = time.time()
            proxy.freeze()
            wait_robot(c, "lk-1", lambda r: not r["online"], timeout=10)
            offline_after = time.time() - frozen_at
            # 1.5 x keepalive after the last message, + the server's 0.5 s check period + polling slack
            assert 1.5 * keepalive - 0.2 < offline_after < 1.5 * keepalive + 0.5 + 0.5, offline_after
            r = c.post("/api/robots/lk-1/commands", json={"command": "move_forward"})
            assert r.status_code == 409, r.text
            # on the timeline: the server's own watch (link-silent) or the broker's Last Will (status), both at
            # 1.5 x keepalive of silence, whichever came first (in a clean-clone run Mosquitto's came 0.1 s
            # before the server's check). The server's watch alone: tests/backend/services/fleet/test_link_silence.py
            wait_for(
                lambda: any(
                    e["kind"] == "offline" and e["detail"].get("source") in ("link-silent", "status")
                    for e in c.get("/api/events", params={"robot_id": "lk-1"}).json()
                ),
                5,
                what="the offline event on the timeline",
            )

            proxy.thaw()
            wait_robot(c, "lk-1", lambda r: r["online"], timeout=20)
            wait_for(
                lambda: c.get(
                    "/api/robots/lk-1/telemetry", params={"raw": "true", "start": frozen_at + 2.5, "limit": 10}
                ).json()["points"],
                20,
                what="telemetry from after the freeze",
            )
            pts = c.get(
                "/api/robots/lk-1/telemetry",
                params={"raw": "true", "start": frozen_at - 1, "end": frozen_at + 3, "limit": 1000},
            ).json()["points"]
    finally:
        agent.stop()
        proxy.close()
    moving = [b for a, b in itertools.pairwise(pts) if b["data"]["x"] - a["data"]["x"] > 1e-5]
    assert moving, "the robot was driving when the link froze"
    assert max(p["ts"] for p in moving) - frozen_at < 0.5 + 0.1
