"""Helpers of the export tests: a robot with a big stored stream (an export larger than the sockets'
buffers), a client that sends an export request and reads nothing, the server's export counters."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import orjson

from backend.core.config import Settings
from backend.store.db import create_db_engine
from backend.store.telemetry_inserts import telemetry_insert
from bench.rawhttp import open_unread
from tests.backend.helpers import ProbeRobot, wait_robot
from tests.support.procs import ServerProcess

#: rows of the big stream, each about 1 KB in CSV: an export of ~8 MB, more than the kernel's socket
#: buffers on both sides (4 MB at most here), so a client that reads nothing blocks the server's sends
BIG_ROWS = 8000
EXPORT = "/api/robots/big/telemetry?stream=blob&raw=true&format=csv"


def fill_big(database_url: str, robot_id: str = "big", rows: int = BIG_ROWS) -> float:
    """Stored rows of a ``blob`` stream written straight into the database; returns the first ts."""
    engine = create_db_engine(Settings(database_url=database_url))
    t0 = time.time() - 3600
    pad = "x" * 1000
    values = [
        {
            "robot_id": robot_id,
            "stream": "blob",
            "seq": i,
            "ts": t0 + i * 0.01,
            "x": None,
            "y": None,
            "z": None,
            "yaw": None,
            "payload": orjson.dumps({"i": i, "pad": pad}).decode(),
            "recv_ts": t0 + i * 0.01,
        }
        for i in range(rows)
    ]
    try:
        with engine.begin() as conn:
            conn.execute(telemetry_insert(engine), values)
    finally:
        engine.dispose()
    return t0


@contextmanager
def started(broker: Any, database_url: str, workdir: Any, **env: str) -> Iterator[ServerProcess]:
    server = ServerProcess(broker, database_url, workdir, **env)
    server.start()
    try:
        yield server
    finally:
        server.stop()


def big_robot(server: ServerProcess, mqtt_probe: Any, database_url: str) -> ProbeRobot:
    robot = ProbeRobot(mqtt_probe, "big", sensors=("blob",))
    robot.status()
    with server.client() as c:
        wait_robot(c, "big", lambda r: r["online"])
    fill_big(database_url)
    return robot


def unread(server: ServerProcess, token: str | None = None, path: str = EXPORT) -> Any:
    return open_unread("127.0.0.1", server.port, path, {"Authorization": f"Bearer {token or server.token}"})


def exports(c: Any) -> dict[str, Any]:
    r = c.get("/api/stats")
    assert r.status_code == 200, r.text
    return r.json()["exports"]  # type: ignore[no-any-return]
