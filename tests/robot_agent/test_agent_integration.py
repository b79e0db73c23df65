"""The real agent process against a real Mosquitto: status, telemetry, commands, e-stop, LWT, shutdown."""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import orjson

from fleet_protocol import PROTOCOL_VERSION, EStop, Topics, decode_status, decode_telemetry, dumps, new_command
from tests.support.mqtt import MqttProbe, Received
from tests.support.procs import AgentProcess, wait_for

T = Topics()
Spawn = Callable[..., AgentProcess]
Probe = Callable[..., MqttProbe]


def j(m: Received) -> Any:
    return orjson.loads(m.payload)


def wait_online(probe: MqttProbe, rid: str, timeout: float = 20) -> dict[str, Any]:
    m = probe.wait(lambda m: m.topic == T.status(rid) and j(m)["online"] is True, timeout)
    return dict(j(m))


def positions(probe: MqttProbe, rid: str) -> list[dict[str, Any]]:
    return [j(m) for m in probe.matching(lambda m: m.topic == T.telemetry(rid, "position"))]


def latest_pose(probe: MqttProbe, rid: str, after: float = 0.0) -> dict[str, Any]:
    m = probe.wait(lambda m: m.topic == T.telemetry(rid, "position") and j(m)["ts"] > after, 5)
    return dict(j(m)["data"])


def send(probe: MqttProbe, rid: str, command: str, args: dict[str, Any] | None = None, **kw: Any) -> str:
    cmd = new_command(command, args)
    body = {**cmd.model_dump(), **kw}
    probe.publish(T.cmd(rid), orjson.dumps(body))
    return cmd.id


def acks(probe: MqttProbe, rid: str, cid: str) -> list[tuple[str, str]]:
    return [
        (j(m)["status"], j(m)["reason"]) for m in probe.matching(lambda m: m.topic == T.ack(rid) and j(m)["id"] == cid)
    ]


def wait_ack(probe: MqttProbe, rid: str, cid: str, status: str, timeout: float = 10) -> dict[str, Any]:
    return dict(
        j(probe.wait(lambda m: m.topic == T.ack(rid) and j(m)["id"] == cid and j(m)["status"] == status, timeout))
    )


def test_online_status_retained_with_capabilities(spawn_agent: Spawn, mqtt_probe: Probe) -> None:
    live = mqtt_probe(T.status("r1"))
    spawn_agent("r1")
    wait_online(live, "r1")
    late = mqtt_probe(T.status("r1"))  # subscribes after the fact: sees the retained status
    m = late.wait(lambda m: m.topic == T.status("r1"), 5)
    assert m.retain
    st = decode_status(m.payload)
    assert st.online and st.agent_version and not st.estop and st.buffer_dropped == 0
    assert st.capabilities.commands == [
        "move_forward",
        "move_backward",
        "turn_left",
        "turn_right",
        "stop",
        "drive",
        "goto",
        "follow_path",
    ]
    assert st.capabilities.sensors == ["position", "imu", "health"]
    assert set(st.sensors) == {"position", "imu", "health"} and all(s.ok for s in st.sensors.values())
    assert st.protocol_version == PROTOCOL_VERSION


def test_telemetry_seq_per_stream_at_configured_rate(spawn_agent: Spawn, mqtt_probe: Probe) -> None:
    probe = mqtt_probe(T.all_telemetry())
    spawn_agent("r1", "--position-rate", "40", "--imu-rate", "10")
    probe.wait(lambda m: m.topic.endswith("/position") and j(m)["seq"] >= 100, 15)
    for stream in ("position", "imu"):
        msgs = [
            decode_telemetry(m.payload, stream)
            for m in probe.matching(lambda m, s=stream: m.topic == T.telemetry("r1", s))
        ]
        seqs = [m.seq for m in msgs]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), f"{stream} seq not +1"
        assert seqs[0] == 0
        if stream == "position":
            span = msgs[-1].ts - msgs[0].ts
            rate = (len(msgs) - 1) / span
            assert 30 <= rate <= 50, rate  # ~40 Hz (agent timestamps)
    geo = probe.matching(lambda m: m.topic == T.telemetry("r1", "lighthouse_geometry"))
    assert len(geo) == 1 and geo[0].retain is False  # delivered live; retained flag only set on late subs
    assert len(decode_telemetry(geo[0].payload, "lighthouse_geometry").data["base_stations"]) == 2


def test_command_moves_the_robot_and_is_acked(spawn_agent: Spawn, mqtt_probe: Probe) -> None:
    probe = mqtt_probe(T.ack("r1"), T.telemetry("r1", "position"))
    spawn_agent("r1", "--start-pose", "0,0,0", "--position-rate", "50")
    start = latest_pose(probe, "r1")
    assert math.hypot(start["x"], start["y"]) < 1e-9
    cid = send(probe, "r1", "move_forward", {"speed": 1.0, "duration_s": 1.0})
    wait_ack(probe, "r1", cid, "accepted", 5)
    done = wait_ack(probe, "r1", cid, "done", 5)
    assert acks(probe, "r1", cid) == [("accepted", ""), ("done", "")]
    end = latest_pose(probe, "r1", after=done["ts"] + 0.3)
    assert 0.2 < end["x"] < 0.32 and abs(end["y"]) < 1e-6  # ~0.3 m/s for 1 s (motor lag)
    # stopped by the deadman: no more motion
    later = latest_pose(probe, "r1", after=time.time() + 0.3)
    assert later["x"] == end["x"]

    cid = send(probe, "r1", "turn_left", {"speed": 0.5, "duration_s": 0.5})
    done = wait_ack(probe, "r1", cid, "done", 5)
    turned = latest_pose(probe, "r1", after=done["ts"] + 0.3)
    assert turned["yaw"] > 0.5 and abs(turned["x"] - end["x"]) < 1e-6


def test_expired_command_is_never_executed(spawn_agent: Spawn, mqtt_probe: Probe) -> None:
    probe = mqtt_probe(T.ack("r1"), T.telemetry("r1", "position"))
    spawn_agent("r1", "--start-pose", "0,0,0")
    before = latest_pose(probe, "r1")
    cid = send(probe, "r1", "move_forward", {"speed": 1.0, "duration_s": 2.0}, ts=time.time() - 10, ttl_s=2.0)
    ack = wait_ack(probe, "r1", cid, "expired", 5)
    assert "expired" in ack["reason"]
    after = latest_pose(probe, "r1", after=time.time() + 0.5)
    assert (after["x"], after["y"]) == (before["x"], before["y"])
    assert acks(probe, "r1", cid) == [("expired", ack["reason"])]


def test_estop_stops_latches_survives_reconnect_and_releases(spawn_agent: Spawn, mqtt_probe: Probe) -> None:
    probe = mqtt_probe(T.all_acks(), T.all_telemetry(), T.all_status())
    spawn_agent("r1", "--start-pose", "0,0,0", "--position-rate", "50")
    wait_online(probe, "r1")
    cid = send(probe, "r1", "move_forward", {"speed": 1.0, "duration_s": 5.0})
    wait_ack(probe, "r1", cid, "accepted")
    probe.wait(lambda m: m.topic == T.telemetry("r1", "position") and j(m)["data"]["x"] > 0.02, 5)  # driving
    estop = EStop(ts=time.time(), id="estop-1", reason="test")
    probe.publish(T.estop(), dumps(estop), retain=True)
    wait_ack(probe, "r1", "estop-1", "done", 5)
    assert acks(probe, "r1", cid)[-1] == ("done", "e-stop")
    # the wheels follow their set-point with a 20 ms lag and snap to 0 within ~0.2 s: read after that
    p1 = latest_pose(probe, "r1", after=time.time() + 0.3)
    assert p1["x"] > 0.02
    p2 = latest_pose(probe, "r1", after=time.time() + 0.4)
    assert p2["x"] == p1["x"]
    probe.wait(lambda m: m.topic == T.status("r1") and j(m)["estop"] is True, 5)
    refused = send(probe, "r1", "move_forward")
    assert wait_ack(probe, "r1", refused, "rejected")["reason"] == "e-stop engaged"
    stop = send(probe, "r1", "stop")
    wait_ack(probe, "r1", stop, "done")

    # a robot that connects later gets the retained e-stop and is latched too
    spawn_agent("r2")
    wait_ack(probe, "r2", "estop-1", "done", 20)
    refused2 = send(probe, "r2", "turn_left")
    assert wait_ack(probe, "r2", refused2, "rejected")["reason"] == "e-stop engaged"

    probe.publish(T.estop(), dumps(EStop(ts=time.time(), id="release-1", engaged=False)), retain=True)
    wait_ack(probe, "r1", "release-1", "done")
    wait_ack(probe, "r2", "release-1", "done")
    ok = send(probe, "r1", "move_forward", {"duration_s": 0.2})
    wait_ack(probe, "r1", ok, "done")


def test_kill_9_leaves_the_last_will(spawn_agent: Spawn, mqtt_probe: Probe) -> None:
    probe = mqtt_probe(T.status("r1"))
    agent = spawn_agent("r1", "--keepalive", "2")
    wait_online(probe, "r1")
    t0 = time.monotonic()
    agent.kill()
    m = probe.wait(lambda m: m.topic == T.status("r1") and j(m)["online"] is False, 2 * 1.5 + 2)
    assert time.monotonic() - t0 < 5
    assert j(m)["reason"] == "connection lost"
    late = mqtt_probe(T.status("r1"))
    r = late.wait(lambda m: m.topic == T.status("r1"), 5)
    assert r.retain and j(r)["online"] is False


def test_sigterm_publishes_offline_and_exits_0(spawn_agent: Spawn, mqtt_probe: Probe) -> None:
    probe = mqtt_probe(T.status("r1"), T.ack("r1"))
    agent = spawn_agent("r1")
    wait_online(probe, "r1")
    cid = send(probe, "r1", "move_forward", {"duration_s": 5})
    wait_ack(probe, "r1", cid, "accepted")
    rc = agent.stop()
    assert rc == 0
    m = probe.wait(lambda m: m.topic == T.status("r1") and j(m)["online"] is False, 5)
    assert j(m)["reason"] == "shutdown"
    assert acks(probe, "r1", cid)[-1] == ("done", "shutdown")
    assert "Traceback" not in agent.log.read_text()


def test_malformed_payloads_are_counted_and_agent_keeps_working(spawn_agent: Spawn, mqtt_probe: Probe) -> None:
    probe = mqtt_probe(T.ack("r1"), T.status("r1"))
    agent = spawn_agent("r1")
    wait_online(probe, "r1")
    for junk in (
        b"",
        b"{",
        b"[]",
        b"\xff\xfe",
        b'{"id": "bad-1", "command": "move_forward"}',
        orjson.dumps({"id": "bad-2", "command": "MOVE", "ts": time.time()}),
        b"x" * 300_000,
    ):
        probe.publish(T.cmd("r1"), junk)
    probe.publish(T.estop(), b"not an estop")
    assert wait_ack(probe, "r1", "bad-1", "rejected")["reason"].startswith("bad command")
    wait_ack(probe, "r1", "bad-2", "rejected")
    cid = send(probe, "r1", "move_forward", {"duration_s": 0.2})
    wait_ack(probe, "r1", cid, "done")
    assert agent.alive()
    log = wait_for(lambda: (t := agent.log.read_text()) and "rejected bad_json" in t and t, 5)
    assert "rejected oversize" in log and "rejected bad_command" in log and "rejected bad_estop" in log
    assert "Traceback" not in log


def test_motor_gate_rejects_drive_when_not_operable(spawn_agent: Spawn, mqtt_probe: Probe, tmp_path: Path) -> None:
    cfg = tmp_path / "agent.toml"
    cfg.write_text('[motors]\ntype = "sim"\nfault = "overcurrent"\n')
    probe = mqtt_probe(T.ack("r1"), T.status("r1"))
    spawn_agent("r1", "--config", str(cfg))
    wait_online(probe, "r1")
    cid = send(probe, "r1", "move_backward")
    assert wait_ack(probe, "r1", cid, "rejected")["reason"] == "motor not operable: simulated fault: overcurrent"
    stop = send(probe, "r1", "stop")
    assert [s for s, _ in (wait_ack(probe, "r1", stop, "done") and acks(probe, "r1", stop))] == ["accepted", "done"]


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_legacy_udp_inputs_feed_the_streams_and_a_failing_sensor_does_not_stop_others(
    spawn_agent: Spawn, mqtt_probe: Probe, tmp_path: Path
) -> None:
    ports = {k: _free_udp_port() for k in ("imu", "position", "apriltag")}
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind(("127.0.0.1", 0))  # the IMU port is taken: that sensor fails, the others run
    taken = blocker.getsockname()[1]
    cfg = tmp_path / "agent.toml"
    cfg.write_text(
        # retries at most a second apart: the recovery below is then prompt however long the start took
        "sensor_retry_max_s = 1.0\n"
        f"[legacy_udp]\nimu_port = {taken}\nposition_port = {ports['position']}\n"
        f"apriltag_port = {ports['apriltag']}\n"
        '[[sensors]]\ntype = "position"\nsource = "legacy"\n'
        '[[sensors]]\ntype = "imu"\nsource = "legacy"\n'
        '[[sensors]]\ntype = "apriltag_legacy"\n'
    )
    try:
        probe = mqtt_probe(T.all_telemetry(), T.status("r1"))
        spawn_agent("r1", "--config", str(cfg))
        st = probe.wait(
            lambda m: (
                m.topic == T.status("r1") and j(m)["online"] and j(m)["sensors"].get("imu", {}).get("ok") is False
            ),
            20,
        )
        assert "Address already in use" in j(st)["sensors"]["imu"]["error"]
        assert j(st)["capabilities"]["sensors"] == ["position", "imu", "apriltag_legacy"]

        def pump() -> bool:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(b"not a position", ("127.0.0.1", ports["position"]))
                s.sendto(b"[1.25, -0.5, 0.75]", ("127.0.0.1", ports["position"]))
                s.sendto(b'{"tag_id": 4, "t": [1, 2, 3]}', ("127.0.0.1", ports["apriltag"]))
            return bool(probe.matching(lambda m: m.topic == T.telemetry("r1", "apriltag_legacy"))) and bool(
                probe.matching(lambda m: m.topic == T.telemetry("r1", "position"))
            )

        wait_for(pump, 10, interval=0.2, what="legacy telemetry")
        pos = decode_telemetry(
            probe.matching(lambda m: m.topic == T.telemetry("r1", "position"))[0].payload, "position"
        )
        assert pos.data == {"x": 1.25, "y": -0.5, "z": 0.75, "yaw": None}
        tag = j(probe.matching(lambda m: m.topic == T.telemetry("r1", "apriltag_legacy"))[0])
        assert tag["data"] == {"raw": {"tag_id": 4, "t": [1, 2, 3]}}
        # the IMU recovers (with backoff) once its port is free
        freed = time.time()
        blocker.close()
        # a status said so after the port was freed (an earlier one, before the IMU first failed, may say ok too)
        probe.wait(lambda m: m.at > freed and m.topic == T.status("r1") and j(m)["sensors"]["imu"]["ok"] is True, 20)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(b"0.1,0.2,9.8,0,0,0.5", ("127.0.0.1", taken))
        imu = probe.wait(lambda m: m.topic == T.telemetry("r1", "imu"), 5)
        assert j(imu)["data"] == {"accel": [0.1, 0.2, 9.8], "gyro": [0.0, 0.0, 0.5]}
    finally:
        blocker.close()
