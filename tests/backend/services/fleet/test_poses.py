"""The fleet poses (backend/services/fleet/poses.py) from a real server on a real broker: robots' fixes fed over
MQTT (agents' telemetry and an old-framework robot's topic) come out on ``fleet/poses`` ten times a second as
compact rows with a velocity, an age and the filter flag; an offline robot drops out; and a ``goto`` into
another robot's body is refused over REST (422 ``goal_inside_robot``) while one beside it is sent."""

from __future__ import annotations

import itertools
import statistics
import time
from collections.abc import Callable

import orjson

from fleet_protocol import BODY_RADIUS_M, LEGACY_POSITION_TOPIC, POSES_PERIOD_S, FleetPoses, Topics, decode_poses
from tests.backend.helpers import ProbeRobot, register_legacy, wait_robot
from tests.support.mqtt import MqttProbe
from tests.support.procs import ServerProcess, wait_for

T = Topics()
MOTION = ("stop", "drive", "goto")


def _poses(probe: MqttProbe, predicate: Callable[[FleetPoses], bool], timeout: float = 10.0) -> FleetPoses:
    def _match() -> FleetPoses | None:
        for m in reversed(probe.matching(lambda m: m.topic == T.poses())):
            poses = decode_poses(m.payload)
            if predicate(poses):
                return poses
        return None

    return wait_for(_match, timeout, what="a matching poses message")


def test_poses_carry_every_robots_fix_velocity_and_age_and_a_goto_into_a_body_is_refused(
    server: ServerProcess, mqtt_probe: Callable[..., MqttProbe]
) -> None:
    listener = mqtt_probe(T.poses())
    mover, parked = ProbeRobot(mqtt_probe, "mover", MOTION), ProbeRobot(mqtt_probe, "parked", MOTION)
    mover.status(collision_filter=True)  # an agent with the filter takes its half of the avoidance
    parked.status()  # an older agent says nothing of it: an obstacle, like an old-framework robot
    with server.client() as c:
        register_legacy(c, "old-1")
    # the old-framework robot: its own topic, stored with the server's receive time
    mover.probe.publish(LEGACY_POSITION_TOPIC, orjson.dumps({"robot_id": "old-1", "position": [-1.0, -1.0, 0.0]}))
    parked.telemetry(0, {"x": 1.0, "y": 1.0, "z": 0.0, "yaw": 0.5})
    # 0.5 m/s along +x, a fix every 50 ms on the robot's clock (sent at once: the velocity uses the robot's ts)
    t0 = time.time() - 0.5
    for i in range(11):
        mover.telemetry(i, {"x": 0.025 * i, "y": 0.0, "z": 0.0, "yaw": 0.0}, ts=t0 + 0.05 * i)

    def _all_fixes_in(p: FleetPoses) -> bool:
        """All three robots, the mover at its last fix: a message sent while the server was still taking in the
        mover's eleven fixes has it part of the way (seen on a loaded machine)."""
        rows = {r[0]: r for r in p.robots}
        return set(rows) == {"mover", "parked", "old-1"} and rows["mover"][1] == 0.25

    poses = _poses(listener, _all_fixes_in)
    rows = {r[0]: r for r in poses.robots}
    _, x, y, yaw, vx, vy, age, filtered = rows["mover"]
    assert (x, y, yaw) == (0.25, 0.0, 0.0) and filtered is True
    assert abs(vx - 0.5) < 0.01 and abs(vy) < 1e-9  # over the last 0.3 s of fixes
    assert 0 <= age < 2.0
    assert rows["parked"][1:6] == (1.0, 1.0, 0.5, 0.0, 0.0)  # one fix: no velocity
    assert rows["parked"][7] is False  # its agent does not say it runs the filter
    assert rows["old-1"][1:4] == (-1.0, -1.0, None) and rows["old-1"][7] is False  # an obstacle, no filter
    assert [r[6] for r in poses.robots] == sorted(r[6] for r in poses.robots)  # freshest first
    # ten a second, one server, seq counting up: the median spacing of the messages' times (a loaded
    # machine's stall delays one message, not the rate)
    later = _poses(listener, lambda p: p.seq >= poses.seq + 10, timeout=5.0)
    run = [decode_poses(m.payload) for m in listener.matching(lambda m: m.topic == T.poses())]
    run = [p for p in run if poses.seq <= p.seq <= later.seq]
    assert all(a.seq < b.seq for a, b in itertools.pairwise(run)) and {p.server_id for p in run} == {poses.server_id}
    spacing = statistics.median((b.ts - a.ts) / (b.seq - a.seq) for a, b in itertools.pairwise(run))
    assert 0.8 * POSES_PERIOD_S <= spacing <= 1.5 * POSES_PERIOD_S, spacing

    with server.client() as c:
        # a goto into the parked robot's body: refused, never sent
        inside = {"x": 1.0 + BODY_RADIUS_M * 0.8, "y": 1.0}
        r = c.post("/api/robots/mover/commands", json={"command": "goto", "args": inside})
        assert r.status_code == 422, r.text
        assert r.json()["code"] == "goal_inside_robot"
        assert "'parked'" in r.json()["detail"]
        # beside it, or at the mover's own place: sent
        sent = []
        for goal in ({"x": 1.0, "y": 1.3}, {"x": 0.25, "y": 0.0}):
            r = c.post("/api/robots/mover/commands", json={"command": "goto", "args": goal})
            assert r.status_code == 202, r.text
            sent.append(r.json()["id"])
        # published after the answer: wait for the last; the refused one, asked first, would have come first
        mover.probe.wait(lambda m: m.topic == T.cmd("mover") and orjson.loads(m.payload)["id"] == sent[-1], 5.0)
        assert [cmd["id"] for cmd in mover.commands_received()] == sent
        stats = c.get("/api/stats").json()["poses"]
        assert stats["sent"] >= 10 and stats["own_heard"] >= 1 and stats["acl_problem"] is None

    # a robot that goes offline drops out of the poses
    parked.status(online=False)
    with server.client() as c:
        wait_robot(c, "parked", lambda r: r["online"] is False)
    gone = _poses(listener, lambda p: "parked" not in {r[0] for r in p.robots} and p.seq > later.seq)
    assert {r[0] for r in gone.robots} == {"mover", "old-1"}
