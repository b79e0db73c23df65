"""History as a research tool, in Chromium against a real server, broker and database: an hour of stored
telemetry of two robots (one with a restart-like gap), exported as every stored point (or plainly marked
bucketed), plotted as several fields and robots with min/max bands, lines broken at the gap, units on the
axes, AprilTag fields, and x-y trajectories over the pool outline."""

from __future__ import annotations

import csv
import io
import math
import time
from datetime import UTC, datetime
from typing import Any

import pytest

from tests.backend.helpers import ProbeRobot, publish_burst
from tests.frontend.conftest import server_browser_auth
from tests.support.procs import ServerProcess, wait_for

HOUR = 3600.0
GAP = (1500.0, 1800.0)  # seconds into the hour where r1 published nothing (a restart)


def _pose(t: float, k: int) -> dict[str, float]:
    return {
        "x": round(1.5 * math.cos(t / 60 + k), 6),
        "y": round(1.5 * math.sin(t / 60 + k), 6),
        "z": 0.05,
        "yaw": round((t / 60 + k) % math.tau - math.pi, 6),
    }


def _detection(tag_id: int, z_mm: float) -> dict[str, Any]:
    return {
        "tag_id": tag_id,
        "family": "tag36h11",
        "corners": [[0, 0], [10, 0], [10, 10], [0, 10]],
        "center": [5.0, 5.0],
        "translation_mm": [10.0, -5.0, z_mm],
        "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        "euler_deg": {"roll": 0.0, "pitch": 0.0, "yaw": 12.5},
        "decision_margin": 50.0,
        "pose_error": 1e-6,
    }


@pytest.fixture
def hour(server, mqtt_probe) -> dict[str, Any]:
    return publish_hour(server, mqtt_probe)


def publish_hour(server, mqtt_probe) -> dict[str, Any]:
    """r1: 5 Hz for an hour except the gap; r2: 2 Hz for the hour; r1's apriltag stream: tag 3 for 20 s."""
    t0 = math.floor(time.time()) - HOUR - 5
    r1 = ProbeRobot(mqtt_probe, "r1", sensors=("position", "apriltag"))
    r2 = ProbeRobot(mqtt_probe, "r2")
    r1.status()
    r2.status()
    p1 = [(t0 + i * 0.2) for i in range(int(HOUR * 5))]
    p1 = [t for t in p1 if not (t0 + GAP[0] <= t < t0 + GAP[1])]
    items1 = [(seq, ts, _pose(ts - t0, 0)) for seq, ts in enumerate(p1)]
    items2 = [(seq, t0 + i * 0.5, _pose(i * 0.5, 2)) for seq, i in enumerate(range(int(HOUR * 2)))]
    tags = [
        (
            i,
            t0 + 100 + i * 0.1,
            {
                "frame_seq": i,
                "image_size": [640, 480],
                "camera": {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0},
                "detections": [_detection(3, 800.0 + i)],
            },
        )
        for i in range(200)
    ]
    publish_burst(r1, "position", items1)
    publish_burst(r2, "position", items2)
    publish_burst(r1, "apriltag", tags)
    with server.client() as c:

        def _stored() -> bool:
            counts = {
                (rid, s["stream"]): s["count"]
                for rid in ("r1", "r2")
                for s in c.get(f"/api/robots/{rid}/streams").json()
            }
            return (
                counts.get(("r1", "position")) == len(items1)
                and counts.get(("r2", "position")) == len(items2)
                and counts.get(("r1", "apriltag")) == len(tags)
            )

        wait_for(_stored, 60, what="an hour of telemetry stored")
        # The hour is past: its robots are not in the pool now. Left online, the server would list their last
        # fixes in the fleet's poses for 10 s as stale neighbours, and every real robot within reach of
        # them would creep (a module sharing this server drove a robot 7 s later and it crept 3 cm).
        r1.status(online=False)
        r2.status(online=False)
        wait_for(
            lambda: not any(r["online"] for r in c.get("/api/robots").json() if r["id"] in ("r1", "r2")),
            10,
            what="r1 and r2 offline",
        )
    return {"t0": t0, "end": t0 + HOUR + 1, "r1": items1, "r2": items2, "tags": tags}


def _open(page, q: str) -> None:
    page.goto(f"/history?{q}")
    page.wait_for_function("() => document.getElementById('history-chart').data?.length > 0", timeout=20000)


def _traces(page) -> list[dict[str, Any]]:
    """gd.data of the history chart, dates as epoch seconds."""
    return page.evaluate("""() => document.getElementById('history-chart').data.map((t) => ({
        name: t.name, meta: t.meta, type: t.type, fill: t.fill ?? null, yaxis: t.yaxis ?? 'y',
        color: t.line?.color ?? null,
        x: Array.from(t.x, (v) => (v instanceof Date ? v.getTime() / 1000 : v)), y: Array.from(t.y)}))""")


def _csv(text: str, response: Any) -> tuple[list[str], list[dict[str, str]]]:
    """(the export's description and units, from its response's headers; its rows as ``csv.DictReader``
    reads the file as it is: the header row comes first)."""
    assert not text.startswith("#"), text[:200]
    headers = response.all_headers()
    comments = [f"# {headers['x-fleet-description']}", f"# units: {headers['x-fleet-units']}"]
    return comments, list(csv.DictReader(io.StringIO(text)))


def _export(page: Any) -> tuple[Any, Any]:
    """Click Export CSV: (the download, the export's response)."""
    with (
        page.expect_response(lambda r: "/api/telemetry?" in r.url and "format=csv" in r.url) as answer,
        page.expect_download() as dl,
    ):
        page.get_by_test_id("export-csv").click()
    return dl.value, answer.value


def test_an_hour_exports_every_stored_point_and_a_bucketed_export_says_so(hour, page_factory, tmp_path):
    page, rec = page_factory()
    _open(page, f"robots=r1&stream=position&start={hour['t0']}&end={hour['end']:.0f}&fields=x")
    # the chart of an hour is bucketed, and says so
    info = page.get_by_test_id("history-info")
    assert "bucketed" in info.inner_text()
    download, response = _export(page)
    assert "-raw-" in download.suggested_filename and download.suggested_filename.endswith(".csv")
    path = tmp_path / "raw.csv"
    download.save_as(path)
    comments, rows = _csv(path.read_text(), response)
    assert comments[0] == (
        "# Mollusca Fleet telemetry export of position: the stored points (raw), every row as stored."
    )
    assert "x = m" in comments[1] and "ts = s (Unix epoch, UTC)" in comments[1]
    # every stored point of the hour, exact, not 10,000 (nor 2,000) averaged buckets
    assert len(rows) == len(hour["r1"]) > 10000
    assert [(int(r["seq"]), float(r["ts"]), float(r["x"])) for r in rows] == [
        (seq, ts, d["x"]) for seq, ts, d in hour["r1"]
    ]
    for r in rows[:: len(rows) // 50]:
        iso = datetime.strptime(r["time_utc"], "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=UTC)
        assert abs(iso.timestamp() - float(r["ts"])) < 1e-6
    assert page.get_by_test_id("export-info").inner_text() == (
        f"Exported {len(rows)} stored points (raw, every row as stored)."
    )

    # ticking "bucketed" exports the means, and the file, its name and the page all say so
    page.get_by_test_id("export-bucketed").check()
    download, response = _export(page)
    assert "-bucketed-" in download.suggested_filename
    download.save_as(tmp_path / "bucketed.csv")
    comments, rows = _csv((tmp_path / "bucketed.csv").read_text(), response)
    assert comments[0].startswith(
        "# Mollusca Fleet telemetry export of position: BUCKETED (downsampled), NOT the stored points"
    )
    assert 0 < len(rows) <= 10000 and {"count", "x_min", "x_max"} <= rows[0].keys()
    assert sum(int(r["count"]) for r in rows) == len(hour["r1"])
    assert page.get_by_test_id("export-info").inner_text().startswith(f"Exported {len(rows)} rows BUCKETED")
    assert rec.console_errors == [], rec.console_errors


def test_history_plots_robots_fields_bands_gaps_units_tags_and_trajectories(hour, server, page_factory):
    t0, end = hour["t0"], hour["end"]
    page, rec = page_factory(1280, 800)
    with page.expect_response(lambda r: "/api/robots/r2/telemetry" in r.url) as r2_response:
        _open(page, f"robots=r1,r2&stream=position&start={t0}&end={end:.0f}&fields=x,yaw")
    bucketed = r2_response.value.json()  # what the page was given
    traces = _traces(page)
    page.screenshot(path="/tmp/h_time.png")
    lines = [t for t in traces if t["meta"]["kind"] == "line"]
    # two robots x two fields, one line each; the robot's colour, the field's axis (one per unit)
    assert sorted((t["meta"]["robot"], t["meta"]["field"]) for t in lines) == [
        ("r1", "x"),
        ("r1", "yaw"),
        ("r2", "x"),
        ("r2", "yaw"),
    ]
    assert len({t["color"] for t in lines if t["meta"]["robot"] == "r1"}) == 1
    assert {t["color"] for t in lines if t["meta"]["robot"] == "r1"} != {
        t["color"] for t in lines if t["meta"]["robot"] == "r2"
    }
    layout = page.evaluate(
        "() => { const l = document.getElementById('history-chart').layout;"
        " return [l.yaxis.title.text, l.yaxis2?.title?.text]; }"
    )
    assert layout == ["m", "rad"]
    assert {t["yaxis"] for t in lines if t["meta"]["field"] == "x"} == {"y"}
    assert {t["yaxis"] for t in lines if t["meta"]["field"] == "yaw"} == {"y2"}
    # bucketed: min/max are a band around each line, and not offered as fields of their own
    bands = {(t["meta"]["robot"], t["meta"]["field"]): t for t in traces if t["meta"]["kind"] == "band"}
    assert set(bands) == {("r1", "x"), ("r2", "x")}  # yaw is the bucket's last value: no min/max to draw
    assert all(t["fill"] == "toself" for t in bands.values())
    # the band is the buckets' min..max: one polygon per stretch between gaps (r1 has two), never filled across
    assert bucketed["downsampled"] and bucketed["method"] == "bucket-mean-minmax"
    band = bands[("r2", "x")]
    assert band["y"][: len(bucketed["points"])] == [p["data"]["x_max"] for p in bucketed["points"]]
    assert band["y"][len(bucketed["points"]) : -1] == [p["data"]["x_min"] for p in reversed(bucketed["points"])]
    assert sum(v is None for v in bands[("r1", "x")]["y"]) == 2  # two polygons, each closed by a null
    offered = page.evaluate("() => [...document.getElementById('h-field').options].map((o) => o.value)")
    assert {"x", "y", "z", "yaw"} <= set(offered) and not {"count", "x_min", "x_max"} & set(offered)
    # the gap: exactly one null break in r1's lines, inside the gap; none in r2's
    r1x = next(t for t in lines if t["meta"] == {"robot": "r1", "field": "x", "stream": "position", "kind": "line"})
    r2x = next(t for t in lines if t["meta"]["robot"] == "r2" and t["meta"]["field"] == "x")
    nulls = [i for i, v in enumerate(r1x["y"]) if v is None]
    assert len(nulls) == 1, nulls
    assert t0 + GAP[0] - 5 <= r1x["x"][nulls[0]] <= t0 + GAP[1] + 5
    assert r1x["x"][nulls[0] - 1] < t0 + GAP[0] < t0 + GAP[1] <= r1x["x"][nulls[0] + 1] + 5
    assert all(v is not None for v in r2x["y"])

    # AprilTag fields, with their unit on the axis
    tags = hour["tags"]
    _open(
        page,
        f"robots=r1&stream=apriltag&start={tags[0][1] - 1:.0f}&end={tags[-1][1] + 1:.0f}&fields=tag3.translation_mm[2]",
    )
    offered = page.evaluate("() => [...document.getElementById('h-field').options].map((o) => o.value)")
    assert {"tags", "tag3.translation_mm[2]", "tag3.euler_deg.yaw"} <= set(offered)
    line = next(t for t in _traces(page) if t["meta"]["kind"] == "line")
    assert line["y"] == [d["detections"][0]["translation_mm"][2] for _, _, d in tags]
    assert page.evaluate("() => document.getElementById('history-chart').layout.yaxis.title.text") == "mm"
    # four fields of four units: four y axes, each titled with its unit, none on top of another
    _open(
        page,
        f"robots=r1&stream=apriltag&start={tags[0][1] - 1:.0f}&end={tags[-1][1] + 1:.0f}"
        "&fields=tag3.translation_mm[2],tag3.euler_deg.yaw,tag3.center[0],tags",
    )
    axes = page.evaluate("""() => { const l = document.getElementById('history-chart')._fullLayout;
        return ['yaxis', 'yaxis2', 'yaxis3', 'yaxis4'].map((k) => [l[k].title.text, l[k].side, l[k].position]); }""")
    assert sorted(a[0] for a in axes) == ["(no unit)", "deg", "mm", "px"]
    assert [a[1] for a in axes] == ["left", "right", "right", "right"]
    right = [a[2] for a in axes[2:]]
    assert len(set(right)) == 2 and all(
        p > page.evaluate("() => document.getElementById('history-chart')._fullLayout.xaxis.domain[1]") for p in right
    )

    # the x-y trajectory: stored x/y (not bucketed in a 5-minute window), over the pool outline
    lo, hi = t0 + 600, t0 + 900
    with server.client() as c:
        stored = {
            rid: c.get(f"/api/robots/{rid}/telemetry", params={"start": lo, "end": hi, "max_points": 10000}).json()
            for rid in ("r1", "r2")
        }
        site = c.get("/api/site").json()
    assert not any(s["downsampled"] for s in stored.values())
    _open(page, f"robots=r1,r2&stream=position&start={lo:.0f}&end={hi:.0f}&mode=xy")
    traces = _traces(page)
    for rid in ("r1", "r2"):
        traj = next(t for t in traces if t["meta"].get("robot") == rid)
        assert traj["x"] == [p["data"]["x"] for p in stored[rid]["points"]]
        assert traj["y"] == [p["data"]["y"] for p in stored[rid]["points"]]
    outline = next(t for t in traces if t["meta"]["kind"] == "outline")
    ring = [*site["boundary"], site["boundary"][0]]
    assert list(zip(outline["x"], outline["y"], strict=True)) == [tuple(p) for p in ring]
    colours = page.evaluate(
        "() => document.getElementById('history-chart').data"
        ".filter((t) => t.meta.kind === 'trajectory').map((t) => t.marker.color.slice(0, 3))"
    )
    assert all(c[0] <= c[1] <= c[2] for c in colours)  # markers coloured by time
    assert page.evaluate("() => document.getElementById('history-chart').layout.xaxis.title.text") == "x (m)"
    assert "mode=xy" in page.url
    assert rec.console_errors == [], rec.console_errors


def test_an_export_over_the_servers_limit_is_refused_on_the_page(broker, database_url, workdir, mqtt_probe, browser):
    server = ServerProcess(broker, database_url, workdir, FLEET_HISTORY_EXPORT_MAX_ROWS="100")
    server.start()
    ctx = None
    try:
        robot = ProbeRobot(mqtt_probe, "big-1")
        robot.status()
        t0 = math.floor(time.time()) - 60
        publish_burst(robot, "position", [(i, t0 + i * 0.05, {"x": float(i), "y": 0.0}) for i in range(150)])
        with server.client() as c:
            wait_for(lambda: c.get("/api/robots/big-1/streams").json()[0]["count"] == 150, 15, what="rows stored")
        ctx = browser.new_context(base_url=server.base_url, **server_browser_auth(server))
        page = ctx.new_page()
        downloads: list[Any] = []
        page.on("download", lambda d: downloads.append(d))
        _open(page, f"robots=big-1&stream=position&start={t0 - 1}&end={t0 + 10}&fields=x")
        page.get_by_test_id("export-csv").click()
        info = page.get_by_test_id("export-info")
        info.filter(has_text="export refused").wait_for()
        assert "150 raw rows" in info.inner_text() and "limit of 100" in info.inner_text()
        # the bucketed export is still possible; 150 points fit in its 10,000 buckets, so the server sends
        # the stored points, and the page says that rather than "bucketed"
        page.get_by_test_id("export-bucketed").check()
        with page.expect_download() as dl:
            page.get_by_test_id("export-csv").click()
        assert "-raw-" in dl.value.suggested_filename
        info.filter(has_text="Exported 150 stored points").wait_for()
        assert len(downloads) == 1  # the refused export downloaded nothing
    finally:
        if ctx is not None:
            ctx.close()
        server.stop()
