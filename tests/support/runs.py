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
