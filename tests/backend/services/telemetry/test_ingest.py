"""Telemetry: stored in the DB, queried over REST with SQL downsampling, deduplicated, gaps counted."""

from __future__ import annotations

import time
from datetime import UTC, datetime

import orjson
from sqlalchemy import create_engine, text

from tests.backend.helpers import TOPICS, ProbeRobot, publish_burst, wait_robot
from tests.support.procs import wait_for


def _db_count(database_url: str, robot_id: str, stream: str) -> int:
    engine = create_engine(database_url)
    try:
        with engine.connect() as conn:
            return int(
                conn.execute(
                    text("SELECT count(*) FROM telemetry WHERE robot_id=:r AND stream=:s"),
                    {"r": robot_id, "s": stream},
                ).scalar_one()
            )
    finally:
        engine.dispose()


def _points(c, robot_id: str, expected: int, **params) -> dict:
    def _get():
        r = c.get(f"/api/robots/{robot_id}/telemetry", params=params)
        assert r.status_code == 200, r.text
        body = r.json()
        return body if len(body["points"]) >= expected else None

    return wait_for(_get, 10, what=f"{expected} telemetry points")


def test_telemetry_arrives_in_database_and_rest(server, mqtt_probe, database_url):
    robot = ProbeRobot(mqtt_probe, "r1")
    robot.status()
    t0 = time.time() - 10
    items = [(i, t0 + i * 0.05, {"x": i * 0.1, "y": -i * 0.2, "z": 0.0, "yaw": 0.01 * i}) for i in range(50)]
    publish_burst(robot, "position", items)
    with server.client() as c:
        body = _points(c, "r1", 50)
        assert body["downsampled"] is False and body["method"] == "none"
        assert [p["seq"] for p in body["points"]] == list(range(50))
        assert [p["ts"] for p in body["points"]] == [ts for _, ts, _ in items]
        assert body["points"][7]["data"] == items[7][2]
        robot_state = wait_robot(c, "r1", lambda r: r["position"] is not None and r["position"]["ts"] == items[-1][1])
        assert robot_state["position"]["x"] == items[-1][2]["x"] and robot_state["msg_rate"] > 0
        assert robot_state["last_seen"] is not None
    assert _db_count(database_url, "r1", "position") == 50


def test_duplicates_stored_once_and_gaps_counted(server, mqtt_probe, database_url):
    robot = ProbeRobot(mqtt_probe, "r1")
    robot.status()
    t0 = time.time() - 5
    seqs = [0, 1, 1, 2, 2, 5, 6]  # QoS 1 redeliveries of 1 and 2 (same seq and ts); 3 and 4 lost
    publish_burst(robot, "position", [(s, t0 + s, {"x": float(s), "y": 0.0, "z": 0.0}) for s in seqs])
    with server.client() as c:
        # The last message published (seq 6) is stored: every message before it, the redeliveries too,
        # went through the same ordered path (broker session, dispatcher, one FIFO writer) already.
        wait_for(lambda: 6 in [p["seq"] for p in c.get("/api/robots/r1/telemetry").json()["points"]], 10, what="seq 6")
        body = c.get("/api/robots/r1/telemetry").json()
        assert [p["seq"] for p in body["points"]] == [0, 1, 2, 5, 6]
        streams = {s["stream"]: s for s in c.get("/api/robots/r1/streams").json()}
        assert streams["position"]["count"] == 5
        assert streams["position"]["gaps"] == 2
        assert streams["position"]["out_of_order"] == 2
        assert streams["position"]["first_ts"] == t0 and streams["position"]["last_ts"] == t0 + 6
        stats = c.get("/api/stats").json()
        assert stats["streams"]["r1"]["position"]["gaps"] == 2
    assert _db_count(database_url, "r1", "position") == 5


def test_downsampling_keeps_min_max_and_limit(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "r1", sensors=("position", "battery"))
    robot.status()
    t0 = time.time() - 100
    n = 2000
    items = []
    for i in range(n):
        x = (i % 100) / 100.0
        y = -((i * 7) % 50) / 10.0
        items.append((i, t0 + i * 0.02, {"x": x, "y": y, "z": 0.0, "yaw": 0.0}))
    items[1234] = (1234, items[1234][1], {"x": 55.5, "y": -99.0, "z": 3.0, "yaw": 1.0})  # a spike
    publish_burst(robot, "position", items)
    battery = [(i, t0 + i * 0.1, {"volts": 12.0 - i * 0.001}) for i in range(300)]
    publish_burst(robot, "battery", battery)
    with server.client() as c:
        _points(c, "r1", n, max_points=10000)
        body = c.get("/api/robots/r1/telemetry", params={"max_points": 100}).json()
        pts = body["points"]
        assert body["downsampled"] is True and body["method"] == "bucket-mean-minmax"
        assert 50 <= len(pts) <= 100
        assert [p["ts"] for p in pts] == sorted(p["ts"] for p in pts)
        assert max(p["data"]["x_max"] for p in pts) == 55.5
        assert min(p["data"]["y_min"] for p in pts) == -99.0
        assert min(p["data"]["x_min"] for p in pts) == 0.0
        assert sum(p["data"]["count"] for p in pts) == n
        assert all(p["data"]["x_min"] <= p["data"]["x"] <= p["data"]["x_max"] for p in pts)
        # a time window: ISO 8601 start, epoch end
        start_iso = datetime.fromtimestamp(t0 + 9.99, UTC).isoformat()  # seq 500 is at t0 + 10
        win = c.get("/api/robots/r1/telemetry", params={"start": start_iso, "end": t0 + 11.99}).json()
        assert [p["seq"] for p in win["points"]] == list(range(500, 600))
        # generic stream: last point per bucket
        _points(c, "r1", 300, stream="battery")
        gen = c.get("/api/robots/r1/telemetry", params={"stream": "battery", "max_points": 10}).json()
        assert gen["method"] == "bucket-last" and gen["downsampled"] is True
        assert 5 <= len(gen["points"]) <= 10
        assert gen["points"][-1]["data"] == battery[-1][2] and gen["points"][-1]["seq"] == 299


def test_bad_query_values_are_422(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "r1")
    robot.status()
    with server.client() as c:
        wait_robot(c, "r1", lambda r: r["online"])
        for params in (
            {"max_points": 0},
            {"max_points": 10001},
            {"start": "yesterday"},
            {"end": "nan"},
            {"start": 100, "end": 50},
            {"stream": "bad/stream"},
        ):
            r = c.get("/api/robots/r1/telemetry", params=params)
            assert r.status_code == 422, (params, r.text)
            assert r.json()["detail"]
        assert c.get("/api/robots/nobody/telemetry").status_code == 404
        empty = c.get("/api/robots/r1/telemetry", params={"stream": "imu"}).json()
        assert empty["points"] == [] and empty["downsampled"] is False


def test_non_object_data_rejected_but_other_streams_kept(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "r1", sensors=("position", "battery"))
    robot.status()
    robot.probe.publish(TOPICS.telemetry("r1", "battery"), orjson.dumps({"ts": time.time(), "seq": 0, "data": 5}))
    robot.telemetry(0, {"volts": 11.9}, stream="battery")
    with server.client() as c:
        body = _points(c, "r1", 1, stream="battery")
        assert body["points"][0]["data"] == {"volts": 11.9}
        assert c.get("/api/health").json()["rejects"]["by_reason"]["bad_telemetry"] == 1
