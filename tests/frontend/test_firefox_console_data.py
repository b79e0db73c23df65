"""The console's data views in Firefox too (Debian's firefox-esr over WebDriver BiDi, driven by
tests/frontend/firefox/console_data.mjs) against a real server, broker and two simulated robots: the pool
outline from the server, a colour per robot, the readout, a hold as one command-log row, and the history
page's traces (time and x-y). The Chromium tests go deeper; this proves the same code works in Gecko."""

from __future__ import annotations

import json
import math
import subprocess
import time

import pytest

from tests.backend.helpers import wait_robot
from tests.frontend.console_support import hold_ends, hold_groups
from tests.frontend.test_firefox import FIREFOX, HERE, _node
from tests.support.procs import base_env

# one Firefox at a time: its modules share one pytest-xdist worker (docs/testing.md)
pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("firefox")]

ROBOTS = {"ffa": "-1,-0.5,0", "ffb": "1,0.8,1.57"}


def test_console_data_views_work_in_firefox(server, spawn_agent, tmp_path):
    node = _node()
    for rid, pose in ROBOTS.items():
        spawn_agent(rid, f"--start-pose={pose}")
    with server.client() as c:
        r = c.post("/api/users", json={"username": "ffdata", "password": "firefox-password", "role": "operator"})
        assert r.status_code == 201, r.text
        for rid in ROBOTS:
            wait_robot(c, rid, lambda r: r["online"] and r["position"], timeout=30)
        site = c.get("/api/site").json()
    start = math.floor(time.time()) - 60
    proc = subprocess.run(
        [
            node,
            str(HERE / "console_data.mjs"),
            server.base_url,
            "ffdata",
            "firefox-password",
            *ROBOTS,
            str(start),
            str(start + 600),
        ],
        cwd=HERE,
        env=base_env(FIREFOX=FIREFOX, HOME=str(tmp_path)),
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    seen = json.loads(proc.stdout.strip().splitlines()[-1])
    assert seen["errors"] == [], seen["errors"]
    ring = [*site["boundary"], site["boundary"][0]]
    assert seen["outline"] == [[p[0] for p in ring], [p[1] for p in ring]]
    for rid, c in seen["colours"].items():
        assert all(abs(a - b) <= 3 for a, b in zip(c["got"], c["want"], strict=True)), (rid, c)
    assert (
        sum(abs(a - b) for a, b in zip(seen["colours"]["ffa"]["want"], seen["colours"]["ffb"]["want"], strict=True))
        > 60
    )
    assert seen["readout"].startswith("ffa x -1.000 m · y -0.500 m"), seen["readout"]
    # the hold is one row with every renewal counted (a row per run of renewals: hold_groups, from the server's
    # record; one, unless a stall parted them), plus the stop
    with server.client() as c:
        moves = [
            m
            for m in c.get("/api/robots/ffa/commands", params={"limit": 1000}).json()
            if m["command"] == "move_forward"
        ]
    groups = hold_groups(moves)
    assert sum(len(g) for g in groups) == seen["sent"] - 1 >= 15 and max(len(g) for g in groups) >= 5, groups
    drives = [r for r in seen["logRows"] if r["command"] == "move_forward"]
    assert [int(r["count"]) for r in drives] == [len(g) for g in reversed(groups)], seen["logRows"]
    assert any(hold_ends(max(groups, key=len)) in r["text"] for r in drives), seen["logRows"]
    assert [r["command"] for r in seen["logRows"]] == ["stop", *["move_forward"] * len(groups)]
    lines = [t for t in seen["timeTraces"] if t["meta"]["kind"] == "line"]
    assert sorted((t["meta"]["robot"], t["meta"]["field"]) for t in lines) == [
        ("ffa", "x"),
        ("ffa", "y"),
        ("ffb", "x"),
        ("ffb", "y"),
    ]
    assert len({t["color"] for t in lines}) == 2 and all(t["n"] > 10 for t in lines)
    kinds = sorted((t["meta"]["kind"], t["meta"].get("robot")) for t in seen["xyTraces"])
    assert kinds == [("outline", None), ("trajectory", "ffa"), ("trajectory", "ffb")]
