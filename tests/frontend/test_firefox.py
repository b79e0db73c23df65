"""The dashboard in Firefox too (issue 4 asks for current Chromium and Firefox): Debian's firefox-esr,
driven by tests/frontend/firefox/smoke.mjs over WebDriver BiDi, against a real server, broker and
simulated robots. Login, the live map, hold-to-drive and release, the camera with its AprilTag overlay.
The Chromium tests next to this one go deeper; this one proves the same page works in Gecko."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.backend.helpers import wait_robot
from tests.support.procs import base_env

# one Firefox at a time: its modules share one pytest-xdist worker (docs/testing.md)
pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("firefox")]

HERE = Path(__file__).resolve().parent / "firefox"
FIREFOX = "/usr/bin/firefox-esr"


def _node() -> str:
    node = shutil.which("node")
    if node is None:
        pytest.fail("node missing: scripts/ensure-system-deps.sh installs nodejs")
    if not (HERE / "node_modules" / "puppeteer-core").is_dir():
        pytest.fail("puppeteer-core missing: `make test` runs npm ci in tests/frontend/firefox")
    if not Path(FIREFOX).exists():
        pytest.fail("firefox-esr missing: scripts/ensure-system-deps.sh installs it")
    return node


def test_dashboard_works_in_firefox(server, fleet, spawn_agent, tmp_path):
    node = _node()
    spawn_agent("cam-ff", "--camera", "--start-pose=1,0,0")  # faces tag 0 on the east wall, 1 m away
    with server.client() as c:
        r = c.post("/api/users", json={"username": "ffox", "password": "firefox-password", "role": "operator"})
        assert r.status_code == 201, r.text
        wait_robot(c, "cam-ff", lambda r: "camera" in r["capabilities"]["sensors"] and r["position"], timeout=30)
        start = c.get("/api/robots/snail-1").json()["position"]
    proc = subprocess.run(
        [node, str(HERE / "smoke.mjs"), server.base_url, "ffox", "firefox-password", "snail-1", "cam-ff"],
        cwd=HERE,
        env=base_env(FIREFOX=FIREFOX, HOME=str(tmp_path)),
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    seen = json.loads(proc.stdout.strip().splitlines()[-1])
    assert seen["errors"] == [], seen["errors"]
    assert "Firefox/" in seen["userAgent"], seen["userAgent"]
    assert {"snail-1", "snail-2", "snail-3", "cam-ff"} <= set(seen["plotted"])
    # held: the drive runs; released: it ends at once; the plotted robot moved forward (+x at yaw 0)
    assert seen["activeWhileHeld"] == "move_forward" and seen["activeAfterRelease"] is None
    assert seen["after"][0] - seen["before"][0] > 0.1, (seen["before"], seen["after"])
    assert "ui-button" in seen["commandSources"]
    with server.client() as c:
        end = c.get("/api/robots/snail-1").json()["position"]
    assert math.hypot(end["x"] - start["x"], end["y"] - start["y"]) > 0.1
    # the camera page: frames arrive and the overlay draws the rendered tag's outline
    assert seen["cameraFrames"] >= 5 and seen["overlayPixels"] > 100, seen
