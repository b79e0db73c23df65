"""Bad motion arguments are refused with a reason and change nothing; ``drive`` is mixed within the kinematic
limits, reports what it clamped, and stops at its deadman."""

from __future__ import annotations

from collections.abc import Callable

import orjson

from fleet_protocol import MOTION_STREAM, decode_telemetry, default_pool_site
from tests.support.motion import FakeServer
from tests.support.procs import AgentProcess

Spawn = Callable[..., AgentProcess]

BAD: list[tuple[str, bytes, str]] = [
    ("goto", b'{"x": 1e300, "y": 0}', "x"),
    ("goto", b'{"x": true, "y": 0}', "x"),
    ("goto", b'{"x": "1", "y": 0}', "x"),
    ("goto", b'{"y": 0}', "x"),
    ("goto", b'{"x": 0, "y": 0, "tolerance_m": 0}', "tolerance_m"),
    ("goto", b'{"x": 0, "y": 0, "max_speed": -1}', "max_speed"),
    ("goto", b'{"x": 0, "y": 0, "timeout_s": 1e9}', "timeout_s"),
    ("goto", b'{"x": 0, "y": 0, "speed": 1}', "speed"),
    ("follow_path", b'{"waypoints": []}', "waypoints"),
    ("follow_path", orjson.dumps({"waypoints": [[0.1, 0.1]] * 10_000}), "waypoints"),
    ("follow_path", b'{"waypoints": [[0, 0, 0]]}', "waypoints"),
    ("follow_path", b'{"waypoints": [[0, -1e12]]}', "waypoints"),
    ("follow_path", b'{"waypoints": [[0, 0]], "loop": "yes"}', "loop"),
    ("follow_path", b'{"waypoints": [[0.3, 0.3], [0.3, 0.3]], "loop": true}', "loop"),
    ("drive", b'{"linear": 100, "angular": 0}', "linear"),
    ("drive", b'{"linear": 0.1, "angular": false}', "angular"),
    ("drive", b'{"linear": 0.1, "duration_s": 60}', "duration_s"),
]


def test_bad_motion_args_are_refused(spawn_agent: Spawn, fake_server: FakeServer) -> None:
    srv = fake_server
    srv.publish_site(1, default_pool_site())
    srv.start_heartbeat()
    spawn_agent("a1", "--start-pose=0,0,0")
    srv.wait_online("a1")
    for command, args, field in BAD:
        cid = srv.send_raw_args("a1", command, args)
        final = srv.final_ack("a1", cid, 10)
        assert final["status"] == "rejected" and final["reason"].startswith("bad args") and field in final["reason"], (
            command,
            args[:60],
            final,
        )
    # NaN and 1e400 are not JSON numbers: the message does not parse, is counted, and nothing moves
    for raw in (b'{"x": NaN, "y": 0}', b'{"x": 1e400, "y": 0}'):
        srv.send_raw_args("a1", "goto", raw)
    assert srv.stream("a1", "motion") == []
    # and the robot still takes a good command
    good = srv.send("a1", "goto", {"x": 0.1, "y": 0.0})
    assert srv.final_ack("a1", good, 30)["status"] == "done"


def test_drive_is_clamped_reported_and_stops_at_its_deadman(spawn_agent: Spawn, fake_server: FakeServer) -> None:
    srv = fake_server
    spawn_agent("a2", "--start-pose=0,0,0")  # current off: a stopped robot stands still
    srv.wait_online("a2")
    cid = srv.send("a2", "drive", {"linear": 2.0, "angular": 0.0, "duration_s": 0.5})
    envelope = srv.wait_motion("a2", cid, lambda e: True)
    report = decode_telemetry(orjson.dumps(envelope), MOTION_STREAM).data
    assert report["mode"] == "drive" and report["clamped"] is True
    assert report["requested"] == {"linear": 2.0, "angular": 0.0}
    assert report["setpoint"]["linear"] == 0.2  # max_linear_mps (default 0.2 m/s)
    final = srv.final_ack("a2", cid, 5)
    assert final["status"] == "done"
    # the robot moved while the drive ran and stands still after its deadman
    poses = [(e["ts"], e["data"]["x"]) for e in srv.stream("a2", "position")]
    accepted = srv.ack("a2", cid, "accepted")["ts"]
    during = [x for t, x in poses if accepted <= t <= final["ts"]]
    assert during and max(during) > 0.05
    later = srv.pose("a2", after=final["ts"] + 0.3)
    assert abs(srv.pose("a2", after=final["ts"] + 1.0)["x"] - later["x"]) < 1e-4

    turn = srv.send("a2", "drive", {"linear": 0.15, "angular": 3.0, "duration_s": 0.3})
    report = srv.wait_motion("a2", turn, lambda e: True)["data"]
    assert report["clamped"] is True and report["setpoint"]["angular"] == 1.5  # max_angular_rps
    assert report["setpoint"]["linear"] == 0.15  # the wheels had room for both
