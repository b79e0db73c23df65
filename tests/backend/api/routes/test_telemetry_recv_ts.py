"""recv_ts: the server stores when it received each message beside the robot's ts, and the history answers it
on request (``time=recv_ts``) in JSON, CSV and NDJSON, raw and downsampled, so a plot can use either clock.

The probe robot's clock runs SKEW_S behind the server's: recv_ts - ts must show that skew (and the default
answer must not carry recv_ts at all)."""

from __future__ import annotations

import csv
import io
import time

import orjson

from tests.backend.helpers import ProbeRobot, publish_burst
from tests.support.procs import wait_for

SKEW_S = 30.0


def _stored(c, robot_id: str, stream: str, n: int) -> None:
    def _count() -> bool:
        streams = {s["stream"]: s for s in c.get(f"/api/robots/{robot_id}/streams").json()}
        return streams.get(stream, {}).get("count", 0) >= n

    wait_for(_count, 15, what=f"{n} {stream} rows of {robot_id}")


def _csv_rows(text: str) -> tuple[list[str], list[str], list[list[str]]]:
    """(the leading ``#`` lines of ``comments=true``, the header row, the rows)."""
    lines = text.splitlines()
    comments = [line for line in lines if line.startswith("#")]
    rows = list(csv.reader(io.StringIO("\n".join(lines[len(comments) :]))))
    return comments, rows[0], rows[1:]


def test_recv_ts_is_stored_and_answered_on_request(server, mqtt_probe):
    robot = ProbeRobot(mqtt_probe, "rt1", sensors=("position", "battery"))
    robot.status()
    sent_from = time.time()
    t0 = sent_from - SKEW_S  # the robot's clock is SKEW_S behind
    pos = [(i, t0 + i * 0.01, {"x": float(i), "y": 0.0, "z": 0.0, "yaw": 0.0}) for i in range(300)]
    bat = [(i, t0 + i * 0.01, {"volts": 12.0 - i / 1000}) for i in range(300)]
    publish_burst(robot, "position", pos)
    publish_burst(robot, "battery", bat)
    with server.client() as c:
        _stored(c, "rt1", "position", len(pos))
        _stored(c, "rt1", "battery", len(bat))
        sent_until = time.time()

        def received_now(recv_ts: float | None) -> bool:
            return recv_ts is not None and sent_from - 0.5 <= recv_ts <= sent_until + 0.5

        # default: as before, no recv_ts key
        plain = c.get("/api/robots/rt1/telemetry", params={"raw": "true", "limit": 10}).json()
        assert plain["points"] and all("recv_ts" not in p for p in plain["points"])

        # raw JSON page: every point has the server's receive time, SKEW_S after the robot's ts
        page = c.get("/api/robots/rt1/telemetry", params={"raw": "true", "limit": 1000, "time": "recv_ts"}).json()
        assert [p["seq"] for p in page["points"]] == list(range(300))
        assert [p["ts"] for p in page["points"]] == [ts for _, ts, _ in pos]  # ts stays the robot's
        for p in page["points"]:
            assert received_now(p["recv_ts"]), p
            assert p["recv_ts"] - p["ts"] > SKEW_S - 3.0 - 0.5  # the robot's clock shows as 30 s behind

        # bounded, not downsampled (300 <= max_points)
        small = c.get("/api/robots/rt1/telemetry", params={"time": "recv_ts", "max_points": 1000}).json()
        assert small["method"] == "none" and all(received_now(p["recv_ts"]) for p in small["points"])

        # downsampled: position buckets carry the mean receive time, bucket-last the last row's
        for stream, method in (("position", "bucket-mean-minmax"), ("battery", "bucket-last")):
            body = c.get(
                "/api/robots/rt1/telemetry", params={"stream": stream, "time": "recv_ts", "max_points": 20}
            ).json()
            assert body["method"] == method and len(body["points"]) >= 15
            assert all(received_now(p["recv_ts"]) for p in body["points"]), body["points"][:3]
            ref = page["points"] if stream == "position" else None
            if ref is not None:  # a bucket's mean recv_ts lies within its rows' receive times
                recvs = [p["recv_ts"] for p in ref]
                assert all(min(recvs) <= p["recv_ts"] <= max(recvs) for p in body["points"])

        # CSV: a recv_ts column after seq, its unit said in the comments; equal to the JSON's to the bit
        r = c.get(
            "/api/robots/rt1/telemetry", params={"raw": "true", "format": "csv", "time": "recv_ts", "comments": "true"}
        )
        comments, header, rows = _csv_rows(r.text)
        assert header[:4] == ["ts", "time_utc", "seq", "recv_ts"]
        assert any("recv_ts = " in line and "server clock" in line for line in comments)
        assert "recv_ts = " in r.headers["x-fleet-units"] and "server clock" in r.headers["x-fleet-units"]
        assert [float(row[3]) for row in rows] == [p["recv_ts"] for p in page["points"]]
        default_header = _csv_rows(c.get("/api/robots/rt1/telemetry", params={"raw": "true", "format": "csv"}).text)[1]
        assert "recv_ts" not in default_header

        # NDJSON, several robots/streams at once
        r = c.get(
            "/api/telemetry",
            params={
                "robots": "rt1",
                "streams": "position,battery",
                "raw": "true",
                "format": "ndjson",
                "time": "recv_ts",
            },
        )
        lines = [orjson.loads(line) for line in r.text.splitlines()]
        assert len(lines) == 600 and all(received_now(line["recv_ts"]) for line in lines)

        many = c.get("/api/telemetry", params={"robots": "rt1", "streams": "battery", "time": "recv_ts"}).json()
        assert all(received_now(p["recv_ts"]) for p in many["series"][0]["points"])

        assert c.get("/api/robots/rt1/telemetry", params={"time": "robot"}).status_code == 422
