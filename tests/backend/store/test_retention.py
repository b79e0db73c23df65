"""Rollups and retention: raw telemetry is rolled up into exact per-second and per-minute aggregates
(counts, sums, min/max, last row) that long-range queries read; rows arriving late keep their minute on
raw rows until it is rolled up again; raw rows older than N days are deleted under sealed aggregates,
late rows merge into those; old aggregates are pruned; a running server does all of it in a worker
thread while ingest goes on."""

from __future__ import annotations

import math
import random
import threading
import time
from collections import defaultdict
from typing import Any

from sqlalchemy import Engine, text

from backend.services.telemetry.ingest import telemetry_row
from backend.services.telemetry.rollups import RollupWorker
from backend.store.retention import run_retention
from backend.store.rollup import run_rollup
from backend.store.telemetry_inserts import dirty_marks, minutes_of, telemetry_insert
from backend.store.telemetry_query import query_series
from tests.backend.helpers import TOPICS, ProbeRobot
from tests.support.procs import ServerProcess, wait_for

DAY = 86400.0


def _insert(engine: Engine, rows: list[dict[str, Any]]) -> None:
    """As the writer does it: the rows and their dirty minutes in one transaction."""
    with engine.begin() as conn:
        conn.execute(telemetry_insert(engine), rows)
        conn.execute(dirty_marks(engine), minutes_of(rows))


def _positions(t0: float, n: int, rng: random.Random, robot: str = "r1", dt: float = 0.05) -> list[dict[str, Any]]:
    return [
        telemetry_row(
            robot,
            "position",
            t0 + i * dt,
            i,
            {"x": rng.uniform(-1, 1), "y": rng.uniform(-1, 1), "z": 0.0, "yaw": rng.uniform(-3, 3)},
        )
        for i in range(n)
    ]


def _expected(rows: list[dict[str, Any]], width: float) -> dict[float, dict[str, Any]]:
    buckets: dict[float, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        buckets[math.floor(r["ts"] / width) * width].append(r)
    out = {}
    for b, rs in buckets.items():
        last = max(rs, key=lambda r: (r["ts"], r["seq"]))
        out[b] = {
            "n": len(rs),
            "x_min": min(r["x"] for r in rs),
            "x_max": max(r["x"] for r in rs),
            "y_min": min(r["y"] for r in rs),
            "y_max": max(r["y"] for r in rs),
            "x_sum": sum(r["x"] for r in rs),
            "first_seq": min(rs, key=lambda r: (r["ts"], r["seq"]))["seq"],
            "last_seq": last["seq"],
            "yaw": last["yaw"],
            "payload": last["payload"],
        }
    return out


def _check_aggregates(engine: Engine, rows: list[dict[str, Any]], robot: str = "r1") -> None:
    with engine.connect() as conn:
        for res, width in (("1s", 1.0), ("1m", 60.0)):
            got = {
                r.bucket_ts: r
                for r in conn.execute(
                    text(f"SELECT * FROM telemetry_{res} WHERE robot_id = :r AND stream = 'position'"), {"r": robot}
                )
            }
            want = _expected(rows, width)
            assert set(got) == set(want), res
            for b, w in want.items():
                g = got[b]
                assert (g.n, g.first_seq, g.last_seq, g.yaw, g.payload) == (
                    w["n"],
                    w["first_seq"],
                    w["last_seq"],
                    w["yaw"],
                    w["payload"],
                )
                assert (g.x_min, g.x_max, g.y_min, g.y_max) == (w["x_min"], w["x_max"], w["y_min"], w["y_max"])
                assert math.isclose(g.x_sum, w["x_sum"], rel_tol=1e-9, abs_tol=1e-9) and g.xyz_n == w["n"]


def _same_shape(page: Any, rows: list[dict[str, Any]]) -> None:
    """A bucketed page carries every row once and keeps the extremes and the last row."""
    assert page.method == "bucket-mean-minmax"
    assert sum(p.data["count"] for p in page.points) == len(rows)
    for axis in ("x", "y"):
        assert max(p.data[f"{axis}_max"] for p in page.points) == max(r[axis] for r in rows)
        assert min(p.data[f"{axis}_min"] for p in page.points) == min(r[axis] for r in rows)
    last = max(rows, key=lambda r: (r["ts"], r["seq"]))
    assert page.points[-1].seq == last["seq"] and page.points[-1].data["yaw"] == last["yaw"]
    assert [p.ts for p in page.points] == sorted(p.ts for p in page.points)


def _buckets(page: Any) -> list[tuple[Any, ...]]:
    """What a bucket holds, exactly: its start (the mean time, to the microsecond), count and extremes."""
    keys = ("count", "x_min", "x_max", "y_min", "y_max")
    return [(round(p.ts, 6), *(p.data[k] for k in keys)) for p in page.points]


def test_rollup_is_exact_and_serves_long_ranges(engine):
    rng = random.Random(1)
    now = time.time()
    t0 = math.floor((now - 7200) / 60) * 60 + 7.3  # not aligned: buckets start mid-way
    rows = _positions(t0, 60_000, rng)  # 50 min at 20 Hz
    battery = [telemetry_row("r1", "battery", t0 + i, i, {"volts": 12.0 - i / 1000}) for i in range(600)]
    _insert(engine, rows + battery)

    # Nothing rolled up yet: the same answer from raw rows (every minute is dirty).
    before = query_series(engine, "r1", "position", None, None, 200)
    assert before.sources == ["raw"]
    _same_shape(before, rows)
    long_before = query_series(engine, "r1", "position", t0 - 600, now, 20)

    report = run_rollup(engine, now)
    assert report.minutes_rolled == 51 + 11 and not report.skipped_locked  # position + battery minutes
    _check_aggregates(engine, rows)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM telemetry_dirty")).scalar_one() == 0
    after = query_series(engine, "r1", "position", None, None, 200)
    assert after.sources == ["1s"]  # 15 s buckets: whole minutes come from the per-second table
    _same_shape(after, rows)
    long = query_series(engine, "r1", "position", t0 - 600, now, 20)  # 2 h in 20 points: per-minute table
    assert "1m" in long.sources
    _same_shape(long, rows)
    # and bucket for bucket the same answer as the raw rows gave before the rollup (a second or a minute
    # that straddled a bucket's edge once went whole into one bucket: the history page's band changed)
    assert _buckets(after) == _buckets(before) and len(before.points) > 100
    assert _buckets(long) == _buckets(long_before) and len(long.points) > 10
    last_battery = query_series(engine, "r1", "battery", None, None, 10)
    assert last_battery.method == "bucket-last" and last_battery.points[-1].data == {"volts": 12.0 - 599 / 1000}

    # A late row (a robot flushing its buffer) lands in a rolled-up minute: queries include it at once
    # (its minute is answered from raw rows again), the next rollup folds it in.
    late = telemetry_row("r1", "position", t0 + 0.01, 999_999, {"x": 7.5, "y": -7.5, "z": 0.0, "yaw": 1.0})
    _insert(engine, [late])
    _same_shape(query_series(engine, "r1", "position", None, None, 200), [*rows, late])
    assert run_rollup(engine, now).minutes_rolled == 1
    _check_aggregates(engine, [*rows, late])
    _same_shape(query_series(engine, "r1", "position", None, None, 200), [*rows, late])


def test_retention_deletes_raw_under_sealed_aggregates(engine):
    rng = random.Random(2)
    now = time.time()
    t0 = math.floor((now - 40 * DAY) / 60) * 60 + 3.1
    old = _positions(t0, 6000, rng)  # 300 s at 20 Hz, 40 days ago
    recent = _positions(now - 3600, 100, rng, dt=1.0)
    _insert(engine, old + recent)

    report = RollupWorker(engine, raw_days=30, agg_days=365, interval_s=3600, chunk_rows=1000).run_once(now)
    assert report.raw_rows_deleted == len(old)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM telemetry")).scalar_one() == len(recent)
        assert conn.execute(text("SELECT count(*) FROM telemetry_1m WHERE sealed")).scalar_one() == 6
        assert conn.execute(text("SELECT count(*) FROM telemetry_1m WHERE NOT sealed")).scalar_one() == 0
    run_rollup(engine, now)  # the recent minutes: the rollup job's part
    with engine.connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM telemetry_1m WHERE NOT sealed")).scalar_one() == len(
            {math.floor(r["ts"] / 60) for r in recent}
        )
    _check_aggregates(engine, old + recent)
    _same_shape(query_series(engine, "r1", "position", t0 - 1, t0 + 400, 100), old)  # short range: sealed 1s
    page = query_series(engine, "r1", "position", None, None, 50)
    assert page.sources == ["raw", "1m"] or page.sources == ["1m"]
    _same_shape(page, old + recent)

    # A very late row for a sealed minute: merged into the sealed aggregates, its raw row deleted.
    late = telemetry_row("r1", "position", t0 + 0.01, 99_999, {"x": 9.5, "y": -9.5, "z": 0.0, "yaw": 2.0})
    _insert(engine, [late])
    _same_shape(query_series(engine, "r1", "position", t0 - 1, t0 + 400, 100), [*old, late])
    rolled = run_rollup(engine, now)
    assert rolled.late_rows_merged == 1
    with engine.connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM telemetry WHERE ts < :c"), {"c": now - DAY}).scalar_one() == 0
        row = conn.execute(
            text(
                "SELECT n, x_max, y_min, first_seq, sealed FROM telemetry_1m "
                "WHERE stream = 'position' AND bucket_ts = :b"
            ),
            {"b": math.floor(t0 / 60) * 60},
        ).one()
        assert tuple(row) == (_expected(old, 60.0)[math.floor(t0 / 60) * 60]["n"] + 1, 9.5, -9.5, 0, True)
    _same_shape(query_series(engine, "r1", "position", t0 - 1, t0 + 400, 100), [*old, late])

    # Aggregates older than agg_days go.
    pruned = run_retention(engine, now + 400 * DAY, 30, 365)
    assert pruned.agg_rows_deleted > 0
    with engine.connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM telemetry_1s")).scalar_one() == 0


def test_concurrent_passes_count_each_row_once(engine):
    """Two passes at once (replicas): each raw row is in the aggregates exactly once."""
    now = time.time()
    rows = _positions(now - 40 * DAY, 4000, random.Random(3)) + _positions(
        now - 2 * DAY, 4000, random.Random(4), robot="r2"
    )
    _insert(engine, rows)
    errors: list[BaseException] = []

    def _pass(fn: Any) -> None:
        try:
            fn()
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    jobs = [lambda: run_retention(engine, now, 30, 365, chunk_rows=500), lambda: run_rollup(engine, now)]
    threads = [threading.Thread(target=_pass, args=(j,)) for j in jobs * 2]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert errors == []
    run_retention(engine, now, 30, 365)  # whatever a locked-out pass left
    run_rollup(engine, now)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM telemetry")).scalar_one() == 4000
        for res in ("1s", "1m"):
            assert conn.execute(text(f"SELECT sum(n) FROM telemetry_{res}")).scalar_one() == len(rows)


def test_server_rolls_up_and_retains_while_ingesting(broker, database_url, workdir, mqtt_probe, engine):
    rng = random.Random(5)
    now = time.time()
    old = _positions(now - 3 * DAY, 3000, rng, robot="keep")
    _insert(engine, old)
    with engine.begin() as conn:  # a robot the server knows from its table
        conn.execute(
            text(
                "INSERT INTO robots (id, legacy, agent_version, capabilities, first_seen, last_seen, online) "
                "VALUES ('keep', false, 'old', '{}', :t, :t, false)"
            ),
            {"t": now - 3 * DAY},
        )
    server = ServerProcess(
        broker,
        database_url,
        workdir,
        FLEET_RETENTION_RAW_DAYS="1",
        FLEET_RETENTION_AGG_DAYS="30",
        FLEET_RETENTION_INTERVAL_S="0.5",
        FLEET_ROLLUP_INTERVAL_S="0.5",
    )
    server.start()
    try:
        robot = ProbeRobot(mqtt_probe, "live")
        robot.status()
        topic = TOPICS.telemetry("live", "position")
        t_live = now - 600  # ten minutes ago: whole minutes the rollup takes at once
        info = None
        for i in range(1000):
            payload = f'{{"ts": {t_live + i * 0.5!r}, "seq": {i}, "data": {{"x": {float(i)!r}, "y": 0.0}}}}'
            info = robot.probe.client.publish(topic, payload, qos=1)
        assert info is not None
        info.wait_for_publish(10)

        def _done() -> bool:
            with engine.connect() as conn:
                old_raw = conn.execute(text("SELECT count(*) FROM telemetry WHERE robot_id = 'keep'")).scalar_one()
                live_agg = conn.execute(
                    text("SELECT coalesce(sum(n), 0) FROM telemetry_1m WHERE robot_id = 'live'")
                ).scalar_one()
            return old_raw == 0 and live_agg == 1000

        wait_for(_done, 30, interval=0.3, what="old rows deleted under aggregates, live rows rolled up")
        with server.client() as c:
            assert c.get("/api/robots/live/streams").json()[0]["count"] == 1000  # raw rows are all there
            kept = c.get("/api/robots/keep/streams").json()  # raw rows gone: counted from the sealed rollups
            assert [(x["stream"], x["count"], x["first_ts"], x["last_ts"]) for x in kept] == [
                ("position", len(old), old[0]["ts"], old[-1]["ts"])
            ]
            body = c.get("/api/robots/keep/telemetry", params={"max_points": 100, "start": now - 4 * DAY}).json()
            assert body["sources"] == ["1s"] and body["method"] == "bucket-mean-minmax"  # raw rows are gone
            assert sum(p["data"]["count"] for p in body["points"]) == len(old)
            assert max(p["data"]["x_max"] for p in body["points"]) == max(r["x"] for r in old)
            live = c.get("/api/robots/live/telemetry", params={"max_points": 20, "start": t_live - 1}).json()
            assert sum(p["data"]["count"] for p in live["points"]) == 1000
            assert max(p["data"]["x_max"] for p in live["points"]) == 999.0
    finally:
        server.stop()
