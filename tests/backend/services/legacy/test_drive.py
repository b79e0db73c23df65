"""A velocity ``drive`` to a robot on the old framework: the nearest seed command behind a dead band, through
the legacy relay with its deadman; goals are refused. Unit checks of the mapping, then the real thing: the
server (with the shipped ACL) and a client that behaves exactly like the seed's robot."""

from __future__ import annotations

import time
from typing import Any

import pytest

from backend.services.legacy.drive import (
    LEGACY_DEAD_BAND_ANGULAR_RPS,
    LEGACY_DEAD_BAND_LINEAR_MPS,
    seed_command_for,
)
from tests.backend.services.legacy.test_relay import (  # noqa: F401  (fixtures)
    _online,
    acl_broker,
    legacy_server,
    seed_robots,
)


@pytest.mark.parametrize(
    ("linear", "angular", "seed"),
    [
        (0.0, 0.0, "stop"),
        (0.04, 0.0, "stop"),  # a tiny stick deflection is no full-speed drive
        (-0.04, 0.25, "stop"),
        (0.0, -0.29, "stop"),
        (0.2, 0.0, "move_forward"),
        (-0.2, 0.1, "move_backward"),
        (0.05, 1.0, "turn_left"),  # counter-clockwise
        (0.05, -1.0, "turn_right"),
        (0.3, 0.5, "move_forward"),  # 6 dead bands forward beat 1.7 of turning
        (5.0, 20.0, "move_forward"),
    ],
)
def test_the_nearest_seed_command_behind_a_dead_band(linear: float, angular: float, seed: str) -> None:
    assert seed_command_for(linear, angular) == seed


def test_the_dead_band_edges() -> None:
    assert seed_command_for(LEGACY_DEAD_BAND_LINEAR_MPS, 0.0) == "move_forward"
    assert seed_command_for(0.0, LEGACY_DEAD_BAND_ANGULAR_RPS) == "turn_left"
    assert seed_command_for(LEGACY_DEAD_BAND_LINEAR_MPS * 0.99, LEGACY_DEAD_BAND_ANGULAR_RPS * 0.99) == "stop"


def _drive(c: Any, rid: str, linear: float, angular: float = 0.0, duration_s: float = 0.5) -> Any:
    body = {"command": "drive", "args": {"linear": linear, "angular": angular, "duration_s": duration_s}}
    return c.post(f"/api/robots/{rid}/commands", json=body)


def test_a_velocity_drive_reaches_a_seed_robot_as_its_nearest_command(legacy_server, seed_robots) -> None:  # noqa: F811
    robot = seed_robots("old-v")
    _online(legacy_server, robot)
    with legacy_server.client() as c:
        # a real stick deflection: the seed hears move_forward, then the server's deadman "stop"
        t0 = time.time()
        r = _drive(c, "old-v", 0.2, duration_s=0.5)
        assert r.status_code == 202, r.text
        cid = r.json()["id"]
        fwd = robot.wait_heard("move_forward", t0)
        assert fwd.qos == 0 and robot.driving == "move_forward"
        stop = robot.wait_heard("stop", fwd.at, timeout=5)
        assert stop.at - fwd.at <= 0.5 + 0.3, stop.at - fwd.at
        command = c.get(f"/api/commands/{cid}").json()
        assert command["status"] == "accepted" and "sent as 'move_forward'" in command["reason"], command

        for linear, angular, seed in [(-0.2, 0.0, "move_backward"), (0.0, 1.0, "turn_left"), (0.0, -1.0, "turn_right")]:
            t = time.time()
            assert _drive(c, "old-v", linear, angular, duration_s=0.3).status_code == 202
            assert robot.wait_heard(seed, t).command == seed
            robot.wait_heard("stop", t, timeout=5)

        # driving, then a tiny deflection (inside the dead band): "stop" at once, never a drive string
        t1 = time.time()
        assert _drive(c, "old-v", 0.2, duration_s=5).status_code == 202
        robot.wait_heard("move_forward", t1)
        assert robot.driving == "move_forward"  # it could be stopped
        tiny_at = time.time()
        assert _drive(c, "old-v", 0.02, 0.1, duration_s=5).status_code == 202
        stop = robot.wait_heard("stop", tiny_at, timeout=5)
        assert stop.at - tiny_at <= 0.3 and robot.driving is None
        time.sleep(0.3)
        assert [h.command for h in robot.commands(tiny_at)] == ["stop"]


def test_goals_to_a_seed_robot_are_refused_and_nothing_is_sent(legacy_server, seed_robots) -> None:  # noqa: F811
    robot = seed_robots("old-g")
    _online(legacy_server, robot)
    with legacy_server.client() as c:
        t0 = time.time()
        assert _drive(c, "old-g", 0.2, duration_s=0.3).status_code == 202  # it is reachable
        robot.wait_heard("move_forward", t0)
        robot.wait_heard("stop", t0)
        after = time.time()
        for command, args in [("goto", {"x": 0.2, "y": 0.0}), ("follow_path", {"waypoints": [[0.0, 0.0], [0.3, 0.0]]})]:
            r = c.post("/api/robots/old-g/commands", json={"command": command, "args": args})
            assert r.status_code == 422 and r.json()["code"] == "unsupported_by_legacy", r.text
            assert "old Mollusca framework" in r.json()["detail"]
        time.sleep(0.5)
        assert robot.commands(after) == []
