"""Missions from ``fleet_client`` and ``fleet-client mission`` against a real server, broker and a simulated
agent with every disturbance on: create (and its refusals), start, pause, resume, wait_mission to the end,
abort, and the swept area as GeoJSON and as a PNG that an independent decoder (libpng via OpenCV) reads."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from shapely.geometry import shape

from backend.services.missions.raster import SWEPT
from fleet_client import FleetClient, FleetError, MissionFailed
from tests.support.procs import REPO_ROOT, ServerProcess, base_env

#: 0.8 m x 0.6 m beside the robot: two or three lanes at a 0.3 m sweep, done in well under a minute
AREA = [[-0.7, -0.5], [0.1, -0.5], [0.1, 0.1], [-0.7, 0.1]]


def decode_png(data: bytes) -> np.ndarray:
    bgra = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    assert bgra is not None and bgra.ndim == 3 and bgra.shape[2] == 4, "not an RGBA PNG"
    return cv2.cvtColor(bgra, cv2.COLOR_BGRA2RGBA)


def green_m2(img: np.ndarray, headers: dict[str, str]) -> float:
    res = float(headers["x-fleet-resolution-m"])
    return float(np.all(img == SWEPT, axis=2).sum()) * res * res


def test_a_mission_from_python_runs_to_the_end_and_its_coverage_reads_back(
    sim_robots, pool_site, fleet: FleetClient, server: ServerProcess
) -> None:
    sim_robots(("mc1", -0.5, -0.35, 0.0))
    with pytest.raises(FleetError) as err:
        fleet.create_mission(["mc1", "ghost"], area=AREA, sweep_width_m=0.3)
    assert (err.value.status_code, err.value.code) == (422, "unknown_robot") and "ghost" in err.value.detail
    with pytest.raises(FleetError) as err:
        fleet.create_mission(["mc1"], area=AREA, sweep_width_m=0)
    assert (err.value.status_code, err.value.code) == (422, "validation_error")

    m = fleet.create_mission(["mc1"], name="from python", area=AREA, sweep_width_m=0.3, speed=0.2)
    mid = m["id"]
    assert m["state"] == "draft" and m["parts"][0]["path"]
    assert [x["id"] for x in fleet.missions()] == [mid]
    assert fleet.start_mission(mid)["state"] == "running"
    assert fleet.pause_mission(mid, reason="a look")["state"] == "paused"
    with pytest.raises(FleetError) as err:
        fleet.pause_mission(mid)
    assert (err.value.status_code, err.value.code) == (409, "bad_mission_state")
    assert fleet.wait_mission(mid, timeout=5, until=("paused",))["reason"] == "a look"
    assert fleet.resume_mission(mid)["state"] == "running"
    done = fleet.wait_mission(mid, timeout=150)
    assert done["state"] == "completed", done
    assert [t["to_state"] for t in done["transitions"]] == ["draft", "running", "paused", "running", "completed"]
    assert done["covered_fraction"] >= 0.9, done["covered_fraction"]

    # the swept area, GeoJSON and PNG, agree with each other and with the mission's figure
    swept = shape(fleet.mission_coverage(mid))
    assert swept.area == pytest.approx(done["covered_fraction"] * done["workable_area_m2"], rel=0.02)
    buf = io.BytesIO()
    headers = fleet.mission_coverage_png(mid, buf, px_per_m=200)
    img = decode_png(buf.getvalue())
    assert green_m2(img, headers) == pytest.approx(swept.area, rel=0.05)
    minx, miny, maxx, maxy = (float(v) for v in headers["x-fleet-bounds"].split(","))
    res = float(headers["x-fleet-resolution-m"])
    assert img.shape[:2] == (round((maxy - miny) / res), round((maxx - minx) / res))
    # Accept: image/png alone chooses the PNG; the default is GeoJSON
    with server.client() as c:
        r = c.get(f"/api/missions/{mid}/coverage", headers={"Accept": "image/png"})
        assert r.headers["content-type"] == "image/png" and r.content[:8] == b"\x89PNG\r\n\x1a\n"
        r = c.get(f"/api/missions/{mid}/coverage")
        assert r.headers["content-type"] == "application/geo+json" and r.json()["type"] in ("Polygon", "MultiPolygon")
        assert c.get(f"/api/missions/{mid}/coverage", params={"format": "gif"}).status_code == 422

    # a mission that ends otherwise, or takes too long, raises MissionFailed
    other = fleet.create_mission(["mc1"], area=AREA, sweep_width_m=0.3)["id"]
    with pytest.raises(MissionFailed) as failed:
        fleet.wait_mission(other, timeout=0.2, interval=0.1)
    assert failed.value.state == "timeout" and failed.value.mission["state"] == "draft"
    fleet.abort_mission(other, reason="not needed")
    with pytest.raises(MissionFailed) as failed:
        fleet.wait_mission(other, timeout=5)
    assert (failed.value.state, failed.value.reason) == ("aborted", "not needed")


def _cli(server: ServerProcess, *args: str) -> subprocess.CompletedProcess[str]:
    env = base_env(FLEET_URL=server.base_url, FLEET_TOKEN=server.token or "")
    return subprocess.run(
        [sys.executable, "-m", "fleet_client.cli", "mission", *args],
        env=env,
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_cli_mission_create_start_pause_resume_abort_wait_and_coverage(
    server: ServerProcess, sim_robots, pool_site, tmp_path: Path
) -> None:
    sim_robots(("mc2", -0.5, -0.35, 0.0))
    area = "--area=" + ";".join(f"{x},{y}" for x, y in AREA)
    r = _cli(server, "create", "--robot", "mc2", "--robot", "ghost", area)
    assert r.returncode == 2 and "robots: unknown robots: ghost" in r.stderr, (r.stdout, r.stderr)
    r = _cli(server, "create", "--robot", "mc2", area, "--width", "0.3", "--name", "from a shell")
    assert r.returncode == 0, r.stderr
    mid = json.loads(r.stdout)["id"]
    assert [json.loads(line)["id"] for line in _cli(server, "list").stdout.splitlines()] == [mid]
    assert json.loads(_cli(server, "start", mid).stdout)["state"] == "running"
    assert json.loads(_cli(server, "pause", mid, "--reason", "tea").stdout)["state"] == "paused"
    r = _cli(server, "wait", mid, "--until", "paused", "--timeout", "5")
    assert r.returncode == 0 and json.loads(r.stdout)["reason"] == "tea", (r.stdout, r.stderr)
    assert json.loads(_cli(server, "resume", mid).stdout)["state"] == "running"
    assert json.loads(_cli(server, "abort", mid).stdout)["state"] == "aborted"
    r = _cli(server, "wait", mid, "--timeout", "5")
    assert r.returncode == 1 and "aborted" in r.stderr and json.loads(r.stdout)["state"] == "aborted"
    shown = json.loads(_cli(server, "show", mid).stdout)
    assert [t["to_state"] for t in shown["transitions"]] == ["draft", "running", "paused", "running", "aborted"]
    out = tmp_path / "swept.png"
    r = _cli(server, "coverage", mid, "--format", "png", "-o", str(out))
    assert r.returncode == 0, r.stderr
    img = decode_png(out.read_bytes())
    headers = json.loads(r.stdout)
    assert green_m2(img, headers) == pytest.approx(shown["covered_fraction"] * shown["workable_area_m2"], abs=0.01)
    r = _cli(server, "coverage", mid)
    assert r.returncode == 0 and json.loads(r.stdout)["type"] in ("Polygon", "MultiPolygon", "GeometryCollection")
