"""The alarm banner in Chromium: an alarm raised by a robot's health appears on every page, the robot list
marks the robot, and an operator acknowledges it from the banner."""

from __future__ import annotations

from typing import Any

from tests.backend.helpers import ProbeRobot, wait_robot
from tests.frontend.console_support import answer_held, wait_held

#: The banner's summary counts every robot's alarms, and a module's shared fleet may raise its own (a seq gap
#: on a loaded machine, a drained simulated battery): the checks count this robot's rows, and the summary
#: must agree with the rows it lists.
_ROWS_AGREE = """([robot, active]) => {
  const rows = [...document.querySelectorAll('[data-testid=alarm-list] li')];
  const mine = rows.filter((li) => li.dataset.robot === robot && li.dataset.state === 'active').length;
  const all = rows.filter((li) => li.dataset.state === 'active').length;
  const summary = document.querySelector('[data-testid=alarm-count]').textContent;
  return mine === active && summary.startsWith(`${all} alarm${all > 1 ? 's need' : ' needs'} attention`);
}"""


def test_alarm_banner_appears_and_acknowledge_works(server, mqtt_probe, page_factory):
    robot = ProbeRobot(mqtt_probe, "bat-ui", sensors=("position", "health"))
    robot.status()
    with server.client() as c:
        wait_robot(c, "bat-ui", lambda r: r["online"])
    page, rec = page_factory()
    page.goto("/")
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    banner = page.get_by_test_id("alarm-banner")
    # a fresh robot: nothing of its own is open yet
    assert page.locator("[data-testid=alarm-list] li[data-robot=bat-ui]").count() == 0
    robot.telemetry(0, {"battery_pct": 3.0}, stream="health")
    banner.wait_for()
    page.wait_for_function(_ROWS_AGREE, arg=["bat-ui", 2])
    page.get_by_test_id("alarm-badge-bat-ui").first.wait_for()
    page.get_by_test_id("alarm-toggle").click()
    critical = page.locator("[data-testid=alarm-list] li[data-robot=bat-ui][data-alarm=battery_critical]")
    critical.wait_for()
    critical.locator("button").click()
    page.wait_for_function(
        "() => document.querySelector('[data-testid=alarm-list] li[data-robot=bat-ui][data-alarm=battery_critical]')"
        "?.dataset.state === 'acknowledged'"
    )
    page.wait_for_function(_ROWS_AGREE, arg=["bat-ui", 1])
    # on another page too
    page.get_by_role("link", name="History").first.click()
    assert banner.is_visible()
    with server.client() as c:
        acked = [a for a in c.get("/api/alarms", params={"state": "acknowledged"}).json() if a["robot_id"] == "bat-ui"]
        assert acked[0]["kind"] == "battery_critical" and acked[0]["acked_by"] == "browser-admin"
    # the battery recovers: everything clears and the banner goes
    robot.telemetry(1, {"battery_pct": 90.0}, stream="health")
    page.wait_for_function(
        "() => { const rows = document.querySelectorAll('[data-testid=alarm-list] li');"
        " return ![...rows].some((li) => li.dataset.robot === 'bat-ui')"
        " && document.querySelector('[data-testid=alarm-banner]').hidden === (rows.length === 0); }"
    )
    assert not rec.console_errors


def test_a_list_reply_older_than_an_alarm_never_hides_it(server, mqtt_probe, page_factory):
    """The page loads the open alarms when it starts and when its WebSocket connects, while the socket brings
    new ones. A reply sent before an alarm was raised but read after it wiped the alarm from the banner until
    the next one (a Firefox run saw a critical battery vanish so). Here both loads are held until the alarm
    has been shown, then answered with what the server said when they were sent: nothing."""
    robot = ProbeRobot(mqtt_probe, "late-ui", sensors=("position", "health"))
    robot.status()
    with server.client() as c:
        wait_robot(c, "late-ui", lambda r: r["online"])
        assert c.get("/api/alarms", params={"state": "open"}).json() == []
    page, rec = page_factory()
    held: list[Any] = []
    page.route(lambda url: "/api/alarms?state=open" in url, lambda route: held.append(route))
    page.goto("/")
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    wait_held(page, held, 2, "alarm list loads")  # one as the page starts, one as its socket connects
    robot.telemetry(0, {"battery_pct": 3.0}, stream="health")
    page.wait_for_function(_ROWS_AGREE, arg=["late-ui", 2])
    for route in (held[1], held[0]):  # the newer load's reply first, then the older's
        answer_held(page, route, "[]", "/api/alarms?state=open")
        assert page.evaluate(_ROWS_AGREE, ["late-ui", 2]), "a stale reply hid the alarms"
        assert page.get_by_test_id("alarm-banner").is_visible()
    assert not rec.console_errors, rec.console_errors


def test_an_admin_forgets_a_gone_robot_from_its_page(server, mqtt_probe, page_factory):
    robot = ProbeRobot(mqtt_probe, "gone-1")
    robot.status()
    with server.client() as c:
        wait_robot(c, "gone-1", lambda r: r["online"])
    page, rec = page_factory()
    page.goto("/robots/gone-1")
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    page.get_by_test_id("control-state").wait_for()
    assert page.get_by_test_id("forget-robot").count() == 0  # online: it would come right back
    robot.status(online=False)
    forget = page.get_by_test_id("forget-robot")
    forget.wait_for()
    forget.click()  # arms it
    assert "Press again" in forget.inner_text()
    with server.client() as c:
        assert c.get("/api/robots/gone-1").status_code == 200  # one press forgets nothing
    forget.click()
    page.wait_for_url("**/")
    with server.client() as c:
        wait_robot_gone = [r["id"] for r in c.get("/api/robots").json()]
        assert "gone-1" not in wait_robot_gone
    page.wait_for_function("() => !document.querySelector('[data-testid=robot-row-gone-1]')")
    assert not rec.console_errors
