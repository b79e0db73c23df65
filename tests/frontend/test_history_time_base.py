"""The history page plots on either clock: the robot's ``ts`` or the server's ``recv_ts`` (issue 20). A probe
robot whose clock runs 30 s behind publishes through a real broker to a real server; in Chromium the same
points move 30 s later on the time axis when "on the server's clock" is ticked, and exports carry recv_ts."""

from __future__ import annotations

import time

from tests.backend.helpers import ProbeRobot, publish_burst
from tests.frontend.console_support import open_page
from tests.support.procs import wait_for

SKEW_S = 30.0


def _first_x(page) -> float:
    """Epoch seconds of the first plotted point of the first trace."""
    return page.evaluate(
        "() => { const x = document.getElementById('history-chart').data[0].x[0];"
        " return (x instanceof Date ? x.getTime() : new Date(String(x).replace(' ', 'T')).getTime()) / 1000; }"
    )


def test_history_plots_on_the_robot_or_the_server_clock(server, mqtt_probe, page_factory):
    robot = ProbeRobot(mqtt_probe, "tb-1", sensors=("position",))
    robot.status()
    sent = time.time()
    t0 = sent - SKEW_S
    publish_burst(
        robot, "position", [(i, t0 + i * 0.05, {"x": i * 0.01, "y": 0.0, "z": 0.0, "yaw": 0.0}) for i in range(100)]
    )
    with server.client() as c:
        wait_for(
            lambda: len(c.get("/api/robots/tb-1/telemetry", params={"raw": "true"}).json()["points"]) == 100,
            10,
            what="stored",
        )
    page, rec = open_page(page_factory, "/")
    page.goto(f"/history?robots=tb-1&stream=position&fields=x&start={t0 - 60:.0f}&end={sent + 60:.0f}")
    page.wait_for_function("() => document.getElementById('history-chart').data?.[0]?.x?.length === 100")
    robot_x = _first_x(page)
    assert abs(robot_x - t0) < 0.01  # the robot's clock

    page.get_by_test_id("history-recv-time").check()
    page.get_by_test_id("history-info").filter(has_text="server's clock").wait_for()
    # the burst arrived within moments: on the server's clock the points bunch up (and the plot may break
    # the line where they do), so wait for the axis to move rather than for a point count
    wait_for(lambda: _first_x(page) > t0 + 10, 10, what="the points on the server's clock")
    server_x = _first_x(page)
    assert sent - 1.0 <= server_x <= time.time()  # when the server received it
    assert abs((server_x - robot_x) - SKEW_S) < 5.0
    assert "time=recv_ts" in page.url  # a link keeps the choice

    with page.expect_download() as dl:
        page.get_by_test_id("export-csv").click()
    with open(dl.value.path()) as f:
        text = f.read()
    header = next(line for line in text.splitlines() if not line.startswith("#"))
    assert header.split(",")[:5] == ["robot_id", "stream", "ts", "time_utc", "seq"] and "recv_ts" in header.split(",")
    assert rec.console_errors == [], rec.console_errors
