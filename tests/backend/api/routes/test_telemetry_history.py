"""History queries: exports row-exact against what was published, fields, paging, limits, several robots,
downsampling that keeps min/max, events and commands by time range."""

from __future__ import annotations

import csv
import io
import random
import time
from datetime import UTC, datetime

import duckdb
import httpx
import orjson
import pandas

from tests.backend.helpers import ProbeRobot, publish_burst, wait_robot
from tests.support.procs import ServerProcess, wait_for


def _stored(c, robot_id: str, stream: str, n: int) -> None:
    def _count() -> bool:
        streams = {s["stream"]: s for s in c.get(f"/api/robots/{robot_id}/streams").json()}
        return streams.get(stream, {}).get("count", 0) >= n

    wait_for(_count, 15, what=f"{n} {stream} rows of {robot_id}")


def _csv(r: httpx.Response) -> tuple[list[str], list[list[str]]]:
    """(the description and units as the two comment lines ``comments=true`` writes, the header row and
    rows): the header row comes first, the description and units in X-Fleet-Description and X-Fleet-Units."""
    assert not r.text.startswith("#"), r.text[:200]
    comments = [f"# {r.headers['x-fleet-description']}", f"# units: {r.headers['x-fleet-units']}"]
    return comments, list(csv.reader(io.StringIO(r.text)))


def _iso(ts: float) -> str:
    return datetime.fromtimestamp(ts, tz=UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _positions(n: int, t0: float, rng: random.Random) -> list[tuple[int, float, dict]]:
    return [
        (
            i,
            t0 + i * 0.02 + rng.random() * 1e-3,
            {"x": rng.uniform(-2, 2), "y": rng.uniform(-2, 2), "z": rng.uniform(0, 0.1), "yaw": rng.uniform(-3, 3)},
        )
        for i in range(n)
    ]


def test_exports_are_row_exact(server, mqtt_probe, tmp_path):
    rng = random.Random(7)
    robot = ProbeRobot(mqtt_probe, "h1", sensors=("position", "imu"))
    robot.status()
    t0 = time.time() - 600
    pos = _positions(1500, t0, rng)
    imu = [
        (i, t0 + i * 0.1, {"accel": [rng.random(), rng.random(), 9.81], "gyro": [0.0, rng.random(), -1e-7]})
        for i in range(120)
    ]
    publish_burst(robot, "position", pos)
    publish_burst(robot, "imu", imu)
    expected_pos = [(ts, seq, d) for seq, ts, d in pos]
    with server.client() as c:
        _stored(c, "h1", "position", len(pos))
        _stored(c, "h1", "imu", len(imu))

        # JSON raw pages: every row exactly once, in (ts, seq) order, data as published
        got, cursor, pages = [], None, 0
        while True:
            params = {"raw": "true", "limit": 400, **({"cursor": cursor} if cursor else {})}
            body = c.get("/api/robots/h1/telemetry", params=params).json()
            assert body["method"] == "none" and body["downsampled"] is False
            got += [(p["ts"], p["seq"], p["data"]) for p in body["points"]]
            cursor, pages = body["next_cursor"], pages + 1
            if cursor is None:
                break
        assert pages == 4 and got == expected_pos

        # CSV: same rows, floats read back to the identical double
        r = c.get("/api/robots/h1/telemetry", params={"raw": "true", "format": "csv"})
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
        assert r.headers["x-fleet-method"] == "none" and r.headers["x-fleet-downsampled"] == "false"
        assert r.headers["content-disposition"] == 'attachment; filename="telemetry-position-raw.csv"'
        comments, rows = _csv(r)
        assert comments == [
            "# Mollusca Fleet telemetry export of position: the stored points (raw), every row as stored.",
            "# units: ts = s (Unix epoch, UTC); time_utc = ISO 8601 UTC; x = m; y = m; z = m; yaw = rad",
        ]
        assert rows[0] == ["ts", "time_utc", "seq", "x", "y", "z", "yaw"]
        # as every tool reads it, without options: the header row first
        assert next(csv.DictReader(io.StringIO(r.text))).keys() == {"ts", "time_utc", "seq", "x", "y", "z", "yaw"}
        frame = pandas.read_csv(io.StringIO(r.text))
        assert list(frame.columns) == rows[0] and len(frame) == len(expected_pos)
        assert frame["x"].tolist() == [d["x"] for _, _, d in expected_pos]
        path = tmp_path / "export.csv"
        path.write_bytes(r.content)
        with duckdb.connect() as db:
            got_db = db.execute(f"SELECT seq, x FROM read_csv('{path}') ORDER BY seq").fetchall()
        assert got_db == [(seq, d["x"]) for _, seq, d in expected_pos]
        # comments=true: the form before 2026-11-29, the same two lines before the same header and rows
        old = c.get("/api/robots/h1/telemetry", params={"raw": "true", "format": "csv", "comments": "true"})
        assert old.text.splitlines() == [*comments, *r.text.splitlines()]
        assert pandas.read_csv(io.StringIO(old.text), comment="#").equals(frame)
        assert [
            (float(a), int(b), {"x": float(x), "y": float(y), "z": float(z), "yaw": float(w)})
            for a, _, b, x, y, z, w in rows[1:]
        ] == expected_pos
        # the ISO 8601 column is the same instant as the epoch seconds (to the microsecond)
        assert all(iso == _iso(float(ts)) for ts, iso, *_ in rows[1:])
        iso0 = datetime.strptime(rows[1][1], "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=UTC)
        assert abs(iso0.timestamp() - pos[0][1]) < 1e-6

        # NDJSON, a time window and fields
        lo, hi = pos[100][1], pos[199][1]
        r = c.get(
            "/api/robots/h1/telemetry",
            params={"raw": "true", "format": "ndjson", "start": lo, "end": hi, "fields": "x,yaw"},
        )
        lines = [orjson.loads(line) for line in r.content.splitlines()]
        assert [(x["ts"], x["seq"], x["data"]) for x in lines] == [
            (ts, seq, {"x": d["x"], "yaw": d["yaw"]}) for seq, ts, d in pos[100:200]
        ]
        assert all(x["robot_id"] == "h1" and x["stream"] == "position" for x in lines)

        # imu: a column per number, with its unit
        r = c.get("/api/robots/h1/telemetry", params={"stream": "imu", "raw": "true", "format": "csv"})
        comments, rows = _csv(r)
        # an HTTP header is ASCII: m/s² is m/s^2 there, m/s² in the comment line
        assert comments[1].endswith(
            "; accel[0] = m/s^2; accel[1] = m/s^2; accel[2] = m/s^2; gyro[0] = rad/s; gyro[1] = rad/s; gyro[2] = rad/s"
        ), comments
        old = c.get("/api/robots/h1/telemetry", params={"stream": "imu", "raw": "true", "format": "csv", "comments": 1})
        assert old.text.splitlines()[1].endswith("; gyro[2] = rad/s") and "accel[0] = m/s²;" in old.text, old.text[:400]
        assert rows[0] == ["ts", "time_utc", "seq", "accel[0]", "accel[1]", "accel[2]", "gyro[0]", "gyro[1]", "gyro[2]"]
        assert [
            (float(a), int(b), {"accel": [float(v) for v in rest[:3]], "gyro": [float(v) for v in rest[3:]]})
            for a, _, b, *rest in rows[1:]
        ] == [(ts, s, d) for s, ts, d in imu]
        # a stream of no fixed shape: the data object as a JSON column, its units listed
        r = c.get("/api/telemetry", params={"robots": "h1", "streams": "position,imu", "raw": "true", "format": "csv"})
        comments, rows = _csv(r)
        assert rows[0] == ["robot_id", "stream", "ts", "time_utc", "seq", "data"]
        assert comments[1].endswith(
            "; data of position: x = m, y = m, z = m, yaw = rad; data of imu: accel = m/s^2, gyro = rad/s"
        ), comments
        assert [(float(a), int(b), orjson.loads(d)) for rid, st, a, _, b, d in rows[1:] if st == "imu"] == [
            (ts, s, d) for s, ts, d in imu
        ]

        # paged CSV: limit + cursor in a header
        r = c.get("/api/robots/h1/telemetry", params={"raw": "true", "format": "csv", "limit": 1000})
        first = _csv(r)[1][1:]
        r2 = c.get(
            "/api/robots/h1/telemetry",
            params={"raw": "true", "format": "csv", "limit": 1000, "cursor": r.headers["x-fleet-next-cursor"]},
        )
        assert "x-fleet-next-cursor" not in r2.headers
        second = _csv(r2)[1][1:]
        assert [int(x[2]) for x in first + second] == list(range(len(pos)))

        # bounded JSON (default mode) with fields
        small = c.get("/api/robots/h1/telemetry", params={"start": lo, "end": hi, "fields": "y"}).json()
        assert small["method"] == "none" and small["fields"] == ["y"]
        assert [p["data"] for p in small["points"]] == [{"y": d["y"]} for _, _, d in pos[100:200]]


def test_unbounded_raw_export_is_refused(broker, database_url, workdir, mqtt_probe):
    server = ServerProcess(broker, database_url, workdir, FLEET_HISTORY_EXPORT_MAX_ROWS="100")
    server.start()
    try:
        robot = ProbeRobot(mqtt_probe, "h2")
        robot.status()
        t0 = time.time() - 60
        publish_burst(robot, "position", [(i, t0 + i * 0.05, {"x": float(i), "y": 0.0}) for i in range(150)])
        with server.client() as c:
            _stored(c, "h2", "position", 150)
            for fmt in ("csv", "ndjson"):
                r = c.get("/api/robots/h2/telemetry", params={"raw": "true", "format": fmt})
                assert r.status_code == 422
                assert "150 raw rows" in r.json()["detail"] and "limit of 100" in r.json()["detail"]
            r = c.get("/api/telemetry", params={"robots": "h2", "raw": "true", "format": "csv"})
            assert r.status_code == 422 and "150 raw rows" in r.json()["detail"]
            # bounded alternatives work: a narrower range, a page, or downsampling
            ok = c.get("/api/robots/h2/telemetry", params={"raw": "true", "format": "csv", "end": t0 + 4.97})
            assert ok.status_code == 200 and len(_csv(ok)[1]) == 1 + 100
            page = c.get("/api/robots/h2/telemetry", params={"raw": "true", "format": "csv", "limit": 100})
            assert page.status_code == 200 and page.headers["x-fleet-next-cursor"]
            down = c.get("/api/robots/h2/telemetry", params={"max_points": 10, "format": "csv"})
            assert down.headers["x-fleet-method"] == "bucket-mean-minmax" and len(_csv(down)[1]) <= 11
            # a bucketed export says so in its description and its file name
            assert _csv(down)[0][0].startswith(
                "# Mollusca Fleet telemetry export of position: BUCKETED (downsampled), NOT the stored points: "
                "position rows are "
            )
            assert "bucketed.csv" in down.headers["content-disposition"]
            for params in (
                {"raw": "true", "limit": 10001},
                {"limit": 5},
                {"raw": "true", "cursor": "nope!"},
                {"format": "xml"},
                {"fields": "a b"},
            ):
                r = c.get("/api/robots/h2/telemetry", params=params)
                assert r.status_code == 422, (params, r.text)
    finally:
        server.stop()


def test_several_robots_and_streams_keep_min_max(server, mqtt_probe):
    rng = random.Random(3)
    robots = [ProbeRobot(mqtt_probe, rid, sensors=("position", "battery")) for rid in ("m1", "m2")]
    t0 = time.time() - 300
    series = {}
    for k, robot in enumerate(robots):
        robot.status()
        items = _positions(2000, t0, rng)
        spike = 700 + 300 * k
        items[spike] = (spike, items[spike][1], {"x": 40.0 + k, "y": -50.0 - k, "z": 0.0, "yaw": 0.5})
        series[robot.robot_id] = items
        publish_burst(robot, "position", items)
        publish_burst(robot, "battery", [(i, t0 + i, {"volts": 12.0 - i * 0.01}) for i in range(40)])
    with server.client() as c:
        for robot in robots:
            _stored(c, robot.robot_id, "position", 2000)
            _stored(c, robot.robot_id, "battery", 40)
        body = c.get(
            "/api/telemetry", params={"robots": "m1,m2", "streams": "position,battery", "max_points": 50}
        ).json()
        assert [(s["robot_id"], s["stream"]) for s in body["series"]] == [
            ("m1", "position"),
            ("m1", "battery"),
            ("m2", "position"),
            ("m2", "battery"),
        ]
        for s in body["series"]:
            if s["stream"] == "position":
                items = series[s["robot_id"]]
                assert s["method"] == "bucket-mean-minmax" and s["downsampled"] and len(s["points"]) <= 50
                assert sum(p["data"]["count"] for p in s["points"]) == 2000
                assert max(p["data"]["x_max"] for p in s["points"]) == max(d["x"] for _, _, d in items)
                assert min(p["data"]["y_min"] for p in s["points"]) == min(d["y"] for _, _, d in items)
                assert min(p["data"]["x_min"] for p in s["points"]) == min(d["x"] for _, _, d in items)
                assert s["points"][-1]["seq"] == 1999 and s["points"][-1]["data"]["yaw"] == items[-1][2]["yaw"]
            else:
                assert s["method"] == "none" and len(s["points"]) == 40
        # CSV of the same query: one row per point, robot and stream on each row
        r = c.get(
            "/api/telemetry",
            params={"robots": "m1,m2", "streams": "position", "max_points": 50, "format": "csv", "fields": "x"},
        )
        assert r.headers["x-fleet-method"] == "bucket-mean-minmax" and r.headers["x-fleet-downsampled"] == "true"
        comments, rows = _csv(r)
        assert "BUCKETED" in comments[0] and "x_min = m; x_max = m" in comments[1], comments
        assert rows[0] == ["robot_id", "stream", "ts", "time_utc", "seq", "count", "x", "x_min", "x_max"]
        assert {x[0] for x in rows[1:]} == {"m1", "m2"}
        assert max(float(x[8]) for x in rows[1:] if x[0] == "m2") == 41.0
        # raw NDJSON of both robots, all rows
        r = c.get("/api/telemetry", params={"robots": "m1,m2", "streams": "battery", "raw": "true", "format": "ndjson"})
        lines = [orjson.loads(x) for x in r.content.splitlines()]
        assert [(x["robot_id"], x["seq"]) for x in lines] == [("m1", i) for i in range(40)] + [
            ("m2", i) for i in range(40)
        ]
        assert c.get("/api/telemetry", params={"robots": "m1,nobody"}).status_code == 404
        assert c.get("/api/telemetry", params={"robots": "m1", "streams": "bad/x"}).status_code == 422
        assert c.get("/api/telemetry", params={"robots": "m1", "raw": "true"}).status_code == 422


def test_events_and_commands_by_time_range(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "h3")
    with server.client() as c:
        robot.status()
        wait_robot(c, "h3", lambda r: r["online"])
        ids = []
        marks = []
        for _ in range(3):
            marks.append(time.time())
            cmd = c.post("/api/robots/h3/commands", json={"command": "stop"}).json()
            robot.ack(cmd["id"], "done")
            ids.append(cmd["id"])
            wait_for(lambda cmd=cmd: time.time() > cmd["ts"], 1)  # the next mark falls after this command
        marks.append(time.time())
        wait_for(lambda: all(c.get(f"/api/commands/{i}").json()["status"] == "done" for i in ids), 10)
        middle = c.get("/api/robots/h3/commands", params={"start": marks[1], "end": marks[2]}).json()
        assert [x["id"] for x in middle] == [ids[1]]
        newest_first = c.get("/api/robots/h3/commands", params={"start": marks[0]}).json()
        assert [x["id"] for x in newest_first] == ids[::-1]
        robot.status(online=False)
        wait_robot(c, "h3", lambda r: not r["online"])
        t_off = time.time()
        events = wait_for(
            lambda: [e for e in c.get("/api/events", params={"robot_id": "h3"}).json() if e["kind"] == "offline"],
            10,
            what="offline event",
        )
        assert marks[-1] <= events[0]["ts"] <= t_off
        before = c.get("/api/events", params={"robot_id": "h3", "end": marks[0]}).json()
        assert "offline" not in [e["kind"] for e in before] and "online" in [e["kind"] for e in before]
        window = c.get("/api/events", params={"robot_id": "h3", "start": marks[-1]}).json()
        assert [e["kind"] for e in window] == ["offline"]
