"""``fleet_client`` and the ``fleet-client`` CLI against a real server (authentication on), broker and agent."""

from __future__ import annotations

import asyncio
import csv
import io
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fleet_client import FleetClient, FleetError
from tests.backend.helpers import TOPICS, ProbeRobot
from tests.support.procs import REPO_ROOT, base_env, wait_for


def _cli(server, *args: str, token: str | None = None, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    env = base_env(FLEET_URL=server.base_url, **({"FLEET_TOKEN": token} if token else {}))
    return subprocess.run(
        [sys.executable, "-m", "fleet_client.cli", *args],
        env=env,
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _published(robot: ProbeRobot, n: int) -> list[tuple[int, float, dict]]:
    from fleet_protocol import encode_telemetry

    t0 = time.time() - 120
    items = [(i, t0 + i * 0.05 + 1e-7 * i, {"x": i / 7, "y": -i / 3, "z": 0.0, "yaw": i / 11}) for i in range(n)]
    info = None
    for seq, ts, data in items:
        info = robot.probe.client.publish(
            TOPICS.telemetry(robot.robot_id, "position"), encode_telemetry(seq, data, ts), qos=1
        )
    assert info is not None
    info.wait_for_publish(10)
    return items


def test_client_library(server, spawn_agent, mqtt_probe, tmp_path: Path):
    assert server.token, "the test server runs with authentication on"
    spawn_agent("fc1")
    probe_robot = ProbeRobot(mqtt_probe, "fc2")
    probe_robot.status()
    items = _published(probe_robot, 700)
    with FleetClient(server.base_url, token="wrong-token") as bad:
        with pytest.raises(FleetError) as err:
            bad.robots()
        assert err.value.status_code == 401
    with FleetClient(server.base_url, token=server.token) as fleet:
        robots = wait_for(
            lambda: {r["id"]: r for r in fleet.robots() if r["online"]}.keys() >= {"fc1", "fc2"} and fleet.robots(),
            20,
            what="robots online",
        )
        assert "move_forward" in {r["id"]: r for r in robots}["fc1"]["capabilities"]["commands"]

        # a command, waited for by the server, then one followed up by polling
        done = fleet.send_command("fc1", "move_forward", {"speed": 0.3, "duration_s": 0.2}, wait=5)
        assert done["status"] == "done" and [a["status"] for a in done["acks"]][-1] == "done"
        sent = fleet.send_command("fc1", "stop", wait=None)
        assert sent["status"] == "sent"
        assert fleet.wait_for_ack(sent["id"], timeout=5)["status"] == "done"
        with pytest.raises(FleetError) as err:
            fleet.send_command("fc1", "fly", wait=1)
        assert err.value.status_code == 422 and "fly" in err.value.detail

        # hold: the robot's drives are refused until released; stop still passes
        held = fleet.hold("fc1", reason="cleaning the wheel")
        assert held["held"] is True and fleet.robot("fc1")["hold"]["reason"] == "cleaning the wheel"
        with pytest.raises(FleetError) as err:
            fleet.send_command("fc1", "move_forward", {"duration_s": 0.2}, wait=1)
        assert err.value.status_code == 409 and "held" in err.value.detail
        assert fleet.send_command("fc1", "stop", wait=5)["status"] == "done"
        assert fleet.release_hold("fc1")["held"] is False and fleet.robot("fc1")["hold"] is None
        assert fleet.send_command("fc1", "move_forward", {"duration_s": 0.2}, wait=5)["status"] == "done"

        # history: every stored row, page by page, exactly as published
        wait_for(lambda: fleet.streams("fc2")[0]["count"] == len(items), 10, what="rows stored")
        rows = list(fleet.history_rows("fc2", page_size=300))
        assert [(r["ts"], r["seq"], r["data"]) for r in rows] == [(ts, s, d) for s, ts, d in items]
        bounded = fleet.history("fc2", max_points=20, fields="x")
        assert bounded["method"] == "bucket-mean-minmax" and len(bounded["points"]) <= 20
        assert max(p["data"]["x_max"] for p in bounded["points"]) == items[-1][2]["x"]

        # CSV export to a file, streamed
        out = tmp_path / "fc2.csv"
        headers = fleet.export(out, ["fc2"], "position")
        assert headers["x-fleet-method"] == "none"
        got = list(csv.reader(line for line in io.StringIO(out.read_text()) if not line.startswith("#")))
        assert got[0] == ["robot_id", "stream", "ts", "time_utc", "seq", "x", "y", "z", "yaw"]
        assert [(float(r[2]), int(r[4]), float(r[5])) for r in got[1:]] == [(ts, s, d["x"]) for s, ts, d in items]

        # live telemetry over the WebSocket (Authorization header)
        async def _live() -> list[dict]:
            seen: list[dict] = []
            agen = fleet.live(["fc1"], ["position"])
            try:
                async for msg in agen:
                    if msg["type"] == "telemetry":
                        seen.append(msg)
                        if len(seen) == 5:
                            return seen
            finally:
                await agen.aclose()
            return seen

        live = asyncio.run(asyncio.wait_for(_live(), 15))
        assert [m["robot_id"] for m in live] == ["fc1"] * 5
        assert [m["seq"] for m in live] == sorted(m["seq"] for m in live)
        assert any(e["kind"] == "online" for e in fleet.events(robot_id="fc1"))


def test_cli(server, spawn_agent, mqtt_probe, tmp_path: Path):
    spawn_agent("cli1")
    probe_robot = ProbeRobot(mqtt_probe, "cli2")
    probe_robot.status()
    items = _published(probe_robot, 300)
    with server.client() as c:
        wait_for(
            lambda: c.get("/api/robots/cli1").status_code == 200 and c.get("/api/robots/cli1").json()["online"],
            20,
            what="agent online",
        )
        wait_for(lambda: c.get("/api/robots/cli2/streams").json()[0]["count"] == len(items), 10)

    denied = _cli(server, "robots")
    assert denied.returncode == 2 and "401" in denied.stderr

    listed = _cli(server, "robots", "--json", token=server.token)
    assert listed.returncode == 0, listed.stderr
    assert {"cli1", "cli2"} <= {r["id"] for r in json.loads(listed.stdout)}
    table = _cli(server, "--token", server.token, "robots")
    assert table.returncode == 0 and "cli1" in table.stdout

    cmd = _cli(
        server,
        "command",
        "cli1",
        "turn_left",
        "-a",
        "speed=0.4",
        "-a",
        "duration_s=0.2",
        "--wait",
        "5",
        token=server.token,
    )
    assert cmd.returncode == 0, cmd.stderr
    body = json.loads(cmd.stdout)
    assert body["status"] == "done" and body["args"]["speed"] == 0.4

    out = tmp_path / "cli2.csv"
    hist = _cli(server, "history", "cli2", "--raw", "--format", "csv", "--output", str(out), token=server.token)
    assert hist.returncode == 0, hist.stderr
    rows = list(csv.reader(line for line in io.StringIO(out.read_text()) if not line.startswith("#")))[1:]
    assert [(float(r[2]), int(r[4])) for r in rows] == [(ts, s) for s, ts, _ in items]

    as_rows = _cli(server, "history", "cli2", "--raw", "--format", "rows", "--fields", "y", token=server.token)
    assert [json.loads(line) for line in as_rows.stdout.splitlines()] == [
        {"ts": ts, "seq": s, "data": {"y": d["y"]}} for s, ts, d in items
    ]

    live = _cli(
        server, "live", "--robot", "cli1", "--stream", "position", "--count", "3", token=server.token, timeout=30
    )
    assert live.returncode == 0, live.stderr
    msgs = [json.loads(line) for line in live.stdout.splitlines()]
    assert len(msgs) == 3 and all(m["type"] == "telemetry" and m["robot_id"] == "cli1" for m in msgs)
