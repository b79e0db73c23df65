"""The command log in Chromium against a real server, broker and simulated robot: a held button's 100 ms
renewals are one row ("held 2.0 s, 21 times done"), a keyboard hold is another, and after a reload (or on the
robot's own page) the log comes back from GET /api/robots/{id}/commands instead of "No commands yet"."""

from __future__ import annotations

from typing import Any

from fleet_protocol import FINAL_ACK_STATUSES
from tests.backend.helpers import wait_robot
from tests.frontend.console_support import hold_ends, hold_groups
from tests.support.procs import wait_for


def _commands(server, robot_id: str) -> list[dict[str, Any]]:
    with server.client() as c:
        return c.get(f"/api/robots/{robot_id}/commands", params={"limit": 1000}).json()  # type: ignore[no-any-return]


def _settled(server, robot_id: str, n: int) -> list[dict[str, Any]]:
    """The robot's n commands once every one has its final ack, oldest first."""

    def _check() -> list[dict[str, Any]] | None:
        cmds = _commands(server, robot_id)
        return cmds[::-1] if len(cmds) == n and all(c["status"] in FINAL for c in cmds) else None

    return wait_for(_check, 15, what=f"{n} commands of {robot_id} ended")  # type: ignore[no-any-return]


def _row(page, testid: str, selector: str):
    return page.locator(f"[data-testid={testid}] li{selector}")


FINAL = {s.value for s in FINAL_ACK_STATUSES}


def _check_rows(page, testid: str, hold: list[dict[str, Any]], keys: list[dict[str, Any]]) -> None:
    """Each hold is one row per run of renewals (hold_groups: one row, unless a stall parted them), with how
    long it was held and how its renewals ended; each release's stop is a row of its own."""
    rows = 2
    for source, cmds in (("ui-button", hold), ("ui-keyboard", keys)):
        groups = hold_groups(cmds)
        assert max(len(g) for g in groups) >= 5, [len(g) for g in groups]  # renewals did collapse
        for group in groups:
            row = _row(page, testid, f"[data-source={source}][data-id='{group[-1]['id']}']")
            summary = f"held {group[-1]['ts'] - group[0]['ts']:.1f} s · {hold_ends(group)}" if len(group) > 1 else ""
            row.filter(has_text=summary).wait_for()
            assert row.get_attribute("data-count") == str(len(group))
            if len(group) > 1:
                assert row.get_attribute("data-first-id") == group[0]["id"]
        assert _row(page, testid, f"[data-source={source}][data-command=move_forward]").count() == len(groups)
        rows += len(groups)
    # each release sent one stop: a row of its own, with its timeline
    assert _row(page, testid, "[data-command=stop]").count() == 2
    assert "done +" in _row(page, testid, "[data-command=stop]").first.inner_text()
    assert _row(page, testid, ".empty").count() == 0
    assert _row(page, testid, "").count() == rows  # not 30-odd rows


def test_holds_collapse_into_one_row_and_the_log_survives_a_reload(server, spawn_agent, page_factory):
    spawn_agent("cl-1", "--start-pose=-1,0,0")
    with server.client() as c:
        wait_robot(c, "cl-1", lambda r: r["online"] and r["position"], timeout=30)
    page, rec = page_factory()
    page.goto("/")
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    page.get_by_test_id("command-log").filter(has_text="No commands yet.").wait_for()
    page.get_by_test_id("robot-row-cl-1").click()
    page.wait_for_function("() => window.fleetDebug.selected() === 'cl-1'")

    # hold the forward button for 20 renewals, then the forward key for 10 more
    box = page.locator("#drive-host").get_by_test_id("drive-forward").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.wait_for_function("() => window.fleetDebug.drive().sent >= 20")
    page.mouse.up()
    page.wait_for_function("() => window.fleetDebug.drive().active === null")
    sent = page.evaluate("() => window.fleetDebug.drive().sent")
    page.keyboard.down("ArrowUp")
    page.wait_for_function(f"() => window.fleetDebug.drive().sent >= {sent + 10}")
    page.keyboard.up("ArrowUp")
    total = page.evaluate("() => window.fleetDebug.drive().sent")
    cmds = _settled(server, "cl-1", total)
    hold = [c for c in cmds if c["source"] == "ui-button" and c["command"] == "move_forward"]
    keys = [c for c in cmds if c["source"] == "ui-keyboard" and c["command"] == "move_forward"]
    assert len(hold) >= 20 and len(keys) >= 10 and len(hold) + len(keys) + 2 == total
    _check_rows(page, "command-log", hold, keys)

    # a reload keeps the log: it comes from the server's history, the same rows
    page.reload()
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    _check_rows(page, "command-log", hold, keys)
    # the robot's own page (a deep link) loads its history too
    page.goto("/robots/cl-1")
    _check_rows(page, "robot-command-log", hold, keys)
    assert rec.console_errors == [], rec.console_errors


def test_a_pause_longer_than_the_deadman_starts_a_new_row(server, page_factory):
    """The collapsing rule itself, on commands as the API returns them: same robot, command, speed and
    source within 0.5 s continue a hold; a longer pause, another speed or another robot does not."""
    page, _ = page_factory()
    page.goto("/")
    page.wait_for_function("() => window.fleetDebug")
    rows = page.evaluate("""async () => {
      const { collapseHolds } = await import('/assets/js/drive/commandlog.js');
      const cmd = (id, robot, ts, speed, command = 'move_forward', source = 'ui-button') =>
        ({ id, robot_id: robot, command, source, ts, args: { speed, duration_s: 0.5 }, status: 'done', acks: [] });
      const cmds = [cmd('a', 'r1', 0.0, 0.5), cmd('b', 'r1', 0.1, 0.5), cmd('x', 'r2', 0.15, 0.5),
        cmd('c', 'r1', 0.2, 0.5), cmd('d', 'r1', 0.8, 0.5), cmd('e', 'r1', 0.9, 0.7),
        cmd('f', 'r1', 1.0, undefined, 'stop'), cmd('g', 'r1', 1.05, undefined, 'stop')];
      return collapseHolds(cmds).map((r) => r.cmds.map((c) => c.id).join(''));
    }""")
    assert rows == ["g", "f", "e", "d", "x", "abc"]
