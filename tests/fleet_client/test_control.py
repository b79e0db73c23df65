"""``client.control`` and its socket (/ws/control/{robot}) against a real server and simulated agents.

"Stopped" is measured from the positions the server stored, with the water current off (a stopped robot
still drifts with it); the other disturbances stay on.
"""

from __future__ import annotations

import asyncio
import json
import math
import statistics
import time
from collections.abc import AsyncIterator

import pytest
import websockets

from fleet_client import ControlError, FleetClient, FleetError

pytestmark = pytest.mark.realtime  # wall-clock safety bounds: the realtime lane, alone (docs/testing.md)

NO_CURRENT = ("--no-current",)


def _xy(fleet: FleetClient, rid: str, start: float, end: float) -> list[tuple[float, float, float]]:
    return [
        (r["ts"], r["data"]["x"], r["data"]["y"]) for r in fleet.history_rows(rid, "position", start=start, end=end)
    ]


def _mean(points: list[tuple[float, float, float]]) -> tuple[float, float]:
    return statistics.fmean(p[1] for p in points), statistics.fmean(p[2] for p in points)


def _moved(fleet: FleetClient, rid: str, start: float, end: float) -> float:
    """Distance between the mean of the first and of the last 5 stored fixes in [start, end] (noise ~2 mm)."""
    pts = _xy(fleet, rid, start, end)
    assert len(pts) >= 10, f"only {len(pts)} stored fixes of {rid} in {end - start:.1f} s"
    return math.dist(_mean(pts[:5]), _mean(pts[-5:]))


def test_control_streams_poses_renews_the_deadman_and_stops_on_exit(sim_robots, fleet):
    sim_robots(("c1", 0.0, 0.0, 0.0), extra=NO_CURRENT)

    async def run() -> tuple[float, float, int, int]:
        async with fleet.control("c1", duration_s=0.3, rate_hz=10) as ctl:
            first = await ctl.next_pose()
            assert {"x", "y", "yaw", "ts", "seq"} <= first.keys()
            await ctl.drive(0.1, 0.0)  # once: only the renewals keep it going past the 0.3 s deadman
            started = time.time()
            seqs = [(await ctl.next_pose())["seq"] for _ in range(30)]  # 1.5 s at 20 Hz
            assert seqs == sorted(seqs) and len(set(seqs)) == 30
            return started, time.time(), ctl.resent, len(ctl.errors)

    started, exited, resent, errors = asyncio.run(run())
    assert errors == 0
    assert resent >= 10, f"the set-point was re-sent {resent} times in 1.5 s at 10 Hz"
    time.sleep(2.5)
    # Without the renewals it would stand from started + 0.3 s (current off): ~0 m in this window; with
    # them ~0.1 m/s for >= 1 s, less the motors' noise and asymmetry and any renewal a busy machine delayed.
    moving = _moved(fleet, "c1", started + 0.5, exited)
    assert moving >= 0.05, f"driven at 0.1 m/s for >= 1 s past the deadman, it moved only {moving:.3f} m"
    after = _moved(fleet, "c1", exited + 0.6, exited + 2.0)
    assert after <= 0.01, f"still moving after the block ended: {after:.3f} m in 1.4 s"
    cmds = fleet.commands("c1", limit=50)
    stops = [c for c in cmds if c["command"] == "stop" and c["ts"] >= exited - 0.5]
    assert stops and stops[0]["status"] == "done", [(c["command"], c["status"], c["reason"]) for c in cmds[:5]]


async def aenumerate(items: AsyncIterator[dict]) -> AsyncIterator[tuple[int, dict]]:
    n = 0
    async for item in items:
        yield n, item
        n += 1


def test_an_exception_in_the_block_stops_the_robot_and_propagates(sim_robots, fleet):
    sim_robots(("c2", 0.0, 0.0, 0.0), extra=NO_CURRENT)

    async def run() -> float:
        async with fleet.control("c2") as ctl:
            start: dict | None = None
            async for steps, pose in aenumerate(ctl.poses()):
                await ctl.drive(0.1, 0.2)
                start = start or pose
                assert steps < 600, f"the robot never moved 0.08 m: {start} -> {pose}"
                # the bug strikes once the robot is seen moving (0.08 m) for over a second of fixes: after a
                # fixed number of poses, a loaded machine ended the block before the robot had gone the 0.05 m
                # checked below (0.0499 m)
                gone = math.hypot(pose["x"] - start["x"], pose["y"] - start["y"])
                if gone >= 0.08 and time.time() > started + 1.5:
                    raise RuntimeError("controller bug")
        raise AssertionError("unreachable")

    started = time.time()
    with pytest.raises(RuntimeError, match="controller bug"):
        asyncio.run(run())
    raised = time.time()
    time.sleep(2.5)
    assert _moved(fleet, "c2", started + 0.3, raised) >= 0.05, "the robot never moved: nothing was tested"
    assert _moved(fleet, "c2", raised + 0.6, raised + 2.0) <= 0.01


def test_a_dropped_socket_makes_the_server_stop_the_robot(server, sim_robots, fleet):
    """A controller that dies without a word (its TCP connection just ends) leaves no robot running out
    a long set-point: the server sends ``stop`` when the socket goes."""
    sim_robots(("c3", 0.0, 0.0, 0.0), extra=NO_CURRENT)
    url = f"ws://127.0.0.1:{server.port}/ws/control/c3?token={server.token}"

    async def run() -> float:
        ws = await websockets.connect(url)
        await ws.send(json.dumps({"type": "drive", "linear": 0.1, "angular": 0.0, "duration_s": 5.0, "ref": 1}))
        replies: list[dict] = []
        while not any(m.get("type") == "sent" for m in replies):
            replies += json.loads(await asyncio.wait_for(ws.recv(), 5))
        sent = next(m for m in replies if m["type"] == "sent")
        assert sent["ref"] == 1
        # the robot took it (a busy machine may deliver it late: then it is "expired" and nothing moves)
        for _ in range(100):
            status = (await asyncio.to_thread(fleet.command, sent["id"]))["status"]
            if status != "sent":
                break
            await asyncio.sleep(0.1)
        assert status == "accepted", status
        await asyncio.sleep(1.0)
        ws.transport.abort()  # no close frame, no stop: as if the process died
        return time.time()

    dropped = asyncio.run(run())
    time.sleep(2.5)
    assert _moved(fleet, "c3", dropped - 0.8, dropped) >= 0.05, "the robot never moved: nothing was tested"
    assert _moved(fleet, "c3", dropped + 0.6, dropped + 2.0) <= 0.01, "the robot ran on after its controller died"
    stop = next(c for c in fleet.commands("c3") if c["command"] == "stop")
    assert stop["source"].startswith("control") and stop["ts"] - dropped < 1.0


def test_estop_ends_the_block_with_control_error(sim_robots, fleet):
    sim_robots(("c4", 0.0, 0.0, 0.0))

    async def run() -> None:
        async with fleet.control("c4") as ctl:
            for _ in range(10):
                await ctl.next_pose()
                await ctl.drive(0.05, 0.0)
            await asyncio.to_thread(fleet.estop, "test")
            for _ in range(40):  # the refusal of the next set-point ends the loop
                await ctl.next_pose()
                await ctl.drive(0.05, 0.0)

    try:
        with pytest.raises(ControlError) as err:
            asyncio.run(run())
        assert err.value.code == "estop_engaged"
    finally:
        fleet.release_estop()


def test_bad_messages_unknown_robots_and_viewers_are_refused(server, sim_robots, fleet):
    sim_robots(("c5", 0.0, 0.0, 0.0))
    with pytest.raises(ControlError) as err:
        asyncio.run(fleet.control("nobody").__aenter__())
    assert err.value.code == "unknown_robot"

    async def bad() -> list[dict]:
        async with websockets.connect(f"ws://127.0.0.1:{server.port}/ws/control/c5?token={server.token}") as ws:
            await ws.send(json.dumps({"type": "drive", "linear": 99.0, "ref": "r1"}))
            await ws.send("not json")
            await ws.send(json.dumps({"type": "fly", "ref": 7}))
            errors: list[dict] = []
            while len(errors) < 3:
                errors += [m for m in json.loads(await asyncio.wait_for(ws.recv(), 5)) if m["type"] == "error"]
            return errors

    errors = asyncio.run(bad())
    assert [(e["ref"], e["code"]) for e in errors] == [("r1", "bad_message"), (None, "bad_message"), (7, "bad_message")]
    assert not [c for c in fleet.commands("c5") if c["command"] == "drive"], "a refused set-point went out"

    with server.client() as admin:
        viewer = admin.post("/api/tokens", json={"name": "viewer", "role": "viewer"}).json()["token"]
    with FleetClient(server.base_url, token=viewer) as as_viewer, pytest.raises(FleetError):
        asyncio.run(as_viewer.control("c5").__aenter__())
