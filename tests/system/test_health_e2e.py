"""The health stream end to end, every part real: a simulated ``fleet-agent`` publishes ``health`` at 1 Hz
to Mosquitto, ``fleet-server`` validates and stores it, and the history API returns it. The simulated
battery drains while the robot drives and holds while it stands; what this machine cannot measure is null.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import httpx
import psutil
import pytest

from fleet_protocol import PROTOCOL_VERSION, HealthData
from tests.backend.helpers import wait_robot
from tests.support.procs import wait_for

RID = "hb-1"
START_PCT = 90.0
DRAIN_PCT_PER_S = 0.5  # the simulated battery's default at full speed on both wheels
IDLE_PCT_PER_S = 2.0 / 3600  # its default idle drain
ROUNDING_PCT = 0.01  # battery_pct is published with two decimals


def _idle_bound(a: dict[str, Any], b: dict[str, Any]) -> float:
    """The most two samples may differ while the robot stands still: idle drain plus one rounding step."""
    return IDLE_PCT_PER_S * abs(b["ts"] - a["ts"]) + ROUNDING_PCT + 1e-9


def _health(c: httpx.Client, after: float = 0.0) -> list[dict[str, Any]]:
    r = c.get(f"/api/robots/{RID}/telemetry", params={"stream": "health", "raw": "true", "limit": 1000})
    assert r.status_code == 200, r.text
    return [p for p in r.json()["points"] if p["ts"] > after]


def _samples_after(c: httpx.Client, after: float, n: int, timeout: float = 15) -> list[dict[str, Any]]:
    def enough() -> list[dict[str, Any]] | None:
        pts = _health(c, after)
        return pts if len(pts) >= n else None

    pts: list[dict[str, Any]] = wait_for(enough, timeout, what=f"{n} health samples after {after}")
    return pts


def _machine_has_cpu_temperature() -> bool:
    if Path("/sys/class/thermal/thermal_zone0/temp").exists():
        return True
    temps = psutil.sensors_temperatures() if hasattr(psutil, "sensors_temperatures") else {}
    return any(e.current is not None for entries in temps.values() for e in entries)


@pytest.mark.timeout(120)
def test_health_is_published_at_1hz_stored_and_drains_with_driving(server, spawn_agent) -> None:
    spawn_agent(RID, "--battery-start-pct", str(START_PCT), "--start-pose=0,0,0")
    with server.client() as c:
        wait_robot(c, RID, lambda r: r["online"] and r["position"] is not None, timeout=30)
        first = _samples_after(c, 0.0, 4)

        # 1 Hz, every sample valid against the schema, versions and process figures measured
        ts = [p["ts"] for p in first]
        seqs = [p["seq"] for p in first]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
        assert 0.9 <= (ts[-1] - ts[0]) / (len(ts) - 1) <= 1.1, ts
        for p in first:
            HealthData.model_validate(p["data"])
            assert p["data"]["agent_version"] and p["data"]["protocol_version"] == PROTOCOL_VERSION
            assert p["data"]["mem_used_pct"] is not None and p["data"]["disk_free_mb"] is not None
            assert p["data"]["motor_fault"] is False  # the sim driver knows it has no fault
        data = first[-1]["data"]
        assert START_PCT - 0.05 < data["battery_pct"] <= START_PCT
        assert data["battery_v"] == pytest.approx(6.4 + 2.0 * data["battery_pct"] / 100, abs=0.01)
        assert data["battery_a"] is None  # the simulated battery does not model a current

        # not measurable here: null, never a stand-in value
        if not Path("/proc/net/wireless").exists():
            assert data["wifi_rssi_dbm"] is None and data["wifi_interface"] is None
        assert data["wifi_bitrate_mbps"] is None or data["wifi_interface"] is not None
        if _machine_has_cpu_temperature():
            assert data["cpu_temp_c"] is not None
        else:
            assert data["cpu_temp_c"] is None

        # the clock offset appears once the agent has synced with the server
        synced = wait_for(
            lambda: next((p for p in _health(c) if p["data"]["clock_offset_ms"] is not None), None),
            15,
            what="a health sample with a clock offset",
        )
        assert abs(synced["data"]["clock_offset_ms"]) < 1000  # same machine: milliseconds at most

        # standing still: the charge holds (only the idle drain, 2 %/h)
        standing = _samples_after(c, first[-1]["ts"], 2)
        before = standing[-1]["data"]["battery_pct"]
        assert first[0]["data"]["battery_pct"] - before <= _idle_bound(first[0], standing[-1])

        # drive 2 s at full speed: 0.5 %/s x 2 s = 1 % drained
        r = c.post(
            f"/api/robots/{RID}/commands?wait=10",
            json={"command": "move_forward", "args": {"speed": 1.0, "duration_s": 2.0}},
        )
        assert r.status_code == 200 and r.json()["status"] == "done", r.text
        done_at = time.time()
        after_sample = _samples_after(c, done_at + 0.5, 1)[0]
        after = after_sample["data"]["battery_pct"]
        drained = before - after
        idle = _idle_bound(standing[-1], after_sample)
        assert 0.8 * DRAIN_PCT_PER_S * 2.0 <= drained <= 1.1 * DRAIN_PCT_PER_S * 2.0 + idle, (before, after)

        # stopped again: the charge holds at its new level
        later_sample = _samples_after(c, done_at + 2.5, 1)[0]
        assert after - later_sample["data"]["battery_pct"] <= _idle_bound(after_sample, later_sample)
