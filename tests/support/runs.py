"""Helpers of the run tests: wait for robots, read raw telemetry through the API (the reference an export
is compared with)."""

from __future__ import annotations

from typing import Any

import httpx

from tests.support.procs import wait_for


def wait_online(c: httpx.Client, robots: list[str], timeout: float = 30.0) -> None:
    def _online() -> bool:
        listed = {r["id"]: r for r in c.get("/api/robots").json()}
        return all(rid in listed and listed[rid]["online"] for rid in robots)

    wait_for(_online, timeout, what=f"robots {robots} online")


def wait_stored_past(c: httpx.Client, robots: list[str], ts: float, timeout: float = 20.0) -> None:
    """Until each robot's stored position stream holds a row stamped after ``ts`` and the gap repair has no
    open gap: every row stamped before ``ts`` is then stored (a robot's messages are stored in the order
    they came). On a loaded machine a robot's last second can arrive after a run's stop; a test comparing
    an export with what the API returns must not read the two while it is still coming in."""

    def _stored() -> bool:
        if any(not raw_rows(c, rid, "position", ts, ts + 3600) for rid in robots):
            return False
        return c.get("/api/stats").json()["gap_repair"].get("open", 0) == 0

    wait_for(_stored, timeout, interval=0.2, what=f"{robots}' rows up to {ts} stored")


def raw_rows(c: httpx.Client, robot: str, stream: str, start: float, end: float) -> list[dict[str, Any]]:
    """Every stored row of one stream between start and end (paged through the JSON raw API)."""
    out: list[dict[str, Any]] = []
    params: dict[str, Any] = {"stream": stream, "start": repr(start), "end": repr(end), "raw": "true", "limit": 10000}
    while True:
        r = c.get(f"/api/robots/{robot}/telemetry", params=params)
        assert r.status_code == 200, r.text
        page = r.json()
        out += page["points"]
        if not page["next_cursor"]:
            return out
        params["cursor"] = page["next_cursor"]


def streams_of(c: httpx.Client, robot: str) -> list[str]:
    r = c.get(f"/api/robots/{robot}/streams")
    assert r.status_code == 200, r.text
    return [s["stream"] for s in r.json()]
