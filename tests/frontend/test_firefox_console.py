"""The desktop tests of the console (issue 21's items, and the older dashboard ones) in Firefox: the
Chromium tests' own functions, run unchanged against Debian's firefox-esr through
tests/frontend/firefox_page.py (Playwright's page calls over WebDriver BiDi).

To keep the time small the module shares one Firefox, one broker, one server (SQLite) and one fleet of
three simulated robots; each test gets fresh browser contexts (cookies, storage), and after each the robots
it added are stopped and forgotten, the e-stop released and every control lease let go. The tests still
run in file order, which matters: those that need the fleet where it started, or no command sent yet,
come first; the one that restarts the server comes last. Touch-only tests stay in Chromium (no touch
emulation in Firefox); what runs here and what does not, and why: docs/dashboard.md, "Browsers tested"."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.backend.helpers import driveable, wait_robot
from tests.frontend import (
    test_alarm_banner,
    test_command_log,
    test_console_a11y,
    test_console_layout,
    test_console_touch,
    test_content_security_policy,
    test_control_lease,
    test_dashboard,
    test_drive_deadman,
    test_history_research,
    test_missions_panel,
    test_nothing_moves,
    test_robot_and_history,
    test_users_page,
)
from tests.frontend.conftest import FLEET
from tests.frontend.firefox_page import FirefoxBrowser, FirefoxError, FirefoxPages
from tests.support.mqtt import MqttProbe
from tests.support.procs import AgentProcess, Broker, ServerProcess, agent_spawner

# one Firefox at a time: its modules share one pytest-xdist worker (docs/testing.md)
pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("firefox")]


@pytest.fixture(scope="module")
def firefox(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FirefoxBrowser]:
    browser = FirefoxBrowser(tmp_path_factory.mktemp("firefox-home"))
    try:
        yield browser
    finally:
        browser.close()


# the conftest fixtures of the same names, once per module
@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("firefox-console")


@pytest.fixture(scope="module")
def broker(workdir: Path) -> Iterator[Broker]:
    b = Broker(workdir)
    try:
        b.start()
        yield b
    finally:
        b.stop()


@pytest.fixture(scope="module")
def database_url(workdir: Path) -> str:
    return f"sqlite:///{workdir / 'fleet.db'}"


@pytest.fixture(scope="module")
def server(broker: Broker, database_url: str, workdir: Path) -> Iterator[ServerProcess]:
    s = ServerProcess(broker, database_url, workdir)
    try:
        s.start()  # inside: a server that never became ready is stopped too
        yield s
    finally:
        s.stop()


@pytest.fixture(scope="module")
def spawn_agent(broker: Broker, workdir: Path) -> Iterator[Callable[..., AgentProcess]]:
    with agent_spawner(broker, workdir) as spawn:
        yield spawn


@pytest.fixture(scope="module")
def fleet(server: ServerProcess, spawn_agent: Callable[..., AgentProcess]) -> dict[str, AgentProcess]:
    agents = {rid: spawn_agent(rid, f"--start-pose={pose}") for rid, pose in FLEET.items()}
    with server.client() as c:
        for rid in FLEET:
            wait_robot(c, rid, driveable, timeout=30)
    return agents


@pytest.fixture(scope="module")
def hour(server: ServerProcess, broker: Broker) -> Iterator[dict[str, Any]]:
    """test_history_research's hour of telemetry, published once for the module's two history tests."""
    probes: list[MqttProbe] = []

    def _probe(*subscriptions: str) -> MqttProbe:
        probes.append(MqttProbe(broker.host, broker.port, list(subscriptions)))
        return probes[-1]

    try:
        yield test_history_research.publish_hour(server, _probe)
    finally:
        for p in probes:
            p.close()


@pytest.fixture(autouse=True)
def _released(server: ServerProcess) -> Iterator[None]:
    """Each test leaves the next one what a fresh server would give it: the e-stop released and nobody's
    control lease on any robot (a lease lasts 60 s after its holder's last drive)."""
    yield
    if server.alive():
        with server.client() as c:
            c.post("/api/estop/release", json={"source": "test"})
            for robot in c.get("/api/robots").json():
                if c.get(f"/api/robots/{robot['id']}/lease").json() is not None:
                    assert c.post(f"/api/robots/{robot['id']}/lease", params={"force": "true"}).status_code == 200
                    assert c.delete(f"/api/robots/{robot['id']}/lease").status_code == 204


@pytest.fixture
def ff_pages(firefox: FirefoxBrowser, server: ServerProcess) -> Iterator[FirefoxPages]:
    """The Chromium tests' ``page_factory``, opening Firefox pages."""
    pages = FirefoxPages(firefox, server)
    try:
        yield pages
    finally:
        pages.close()


@contextlib.contextmanager
def _forgotten_after(server: ServerProcess, spawn_agent: Callable[..., AgentProcess]) -> Iterator[Callable[..., Any]]:
    """``spawn_agent`` for one test, whose robots are stopped and forgotten after it: the next test sees
    the fleet as a fresh server would (robot counts, the command log's robots)."""
    spawned: list[AgentProcess] = []

    def _spawn(robot_id: str, *args: str, **env: str) -> AgentProcess:
        spawned.append(spawn_agent(robot_id, *args, **env))
        return spawned[-1]

    try:
        yield _spawn
    finally:
        for agent in spawned:
            agent.stop()
        with server.client() as c:
            for rid in {a.robot_id for a in spawned}:
                wait_robot(c, rid, lambda r: not r["online"], timeout=30)
                assert c.delete(f"/api/robots/{rid}").status_code == 200


def test_firefox_is_gecko_and_the_page_calls_can_fail(firefox, ff_pages):
    """The Playwright calls of firefox_page.py fail where Playwright's would: the tests above them prove
    something only if a missing, hidden, ambiguous or covered element is refused."""
    assert "Firefox/" in firefox.user_agent, firefox.user_agent
    page, rec = ff_pages(logged_in=False)
    page.goto("/login")
    page.get_by_test_id("login-username").wait_for()
    assert page.evaluate("() => navigator.userAgent").count("Firefox/") == 1
    with pytest.raises(FirefoxError, match="timed out"):
        page.get_by_test_id("no-such-thing").wait_for(timeout=300)
    with pytest.raises(FirefoxError, match="timed out"):
        page.wait_for_function("() => document.title === 'never'", timeout=300)
    with pytest.raises(FirefoxError, match="strict mode"):
        page.locator("input").click(timeout=300)
    assert page.get_by_test_id("login-username").is_visible()
    page.evaluate("() => { document.querySelector('[data-testid=login-username]').style.display = 'none'; }")
    assert page.get_by_test_id("login-username").is_hidden()
    with pytest.raises(FirefoxError, match="not visible"):
        page.get_by_test_id("login-username").click(timeout=300)
    # an element under another one cannot be clicked; once uncovered, a real click reaches it
    page.evaluate("""() => { const d = document.createElement('div'); d.id = 'cover';
      Object.assign(d.style, {position: 'fixed', inset: '0', zIndex: 99}); document.body.append(d);
      window.__clicked = 0; document.querySelector('[data-testid=login-submit]')
        .addEventListener('click', (e) => { e.preventDefault(); window.__clicked++; }, true); }""")
    with pytest.raises(FirefoxError, match="actionable"):
        page.get_by_test_id("login-submit").click(timeout=300)
    page.evaluate("() => document.getElementById('cover').remove()")
    page.get_by_test_id("login-submit").click()
    assert page.evaluate("() => window.__clicked") == 1
    # the page moves between measuring and pressing (a banner appears above): the press that lands elsewhere
    # reaches nothing, and the click is tried again where the element now is
    page.mouse.move(1, 1)  # away from the button first: the click's own move is the one that shifts it
    page.evaluate("""() => { window.__clicked = 0; window.__stray = 0;
      document.addEventListener('click', (e) => {
        if (!e.target.closest('[data-testid=login-submit]')) window.__stray++; });
      window.addEventListener('mousemove', () => { if (document.getElementById('shift')) return;
        const d = document.createElement('div'); d.id = 'shift'; document.body.prepend(d);
        Object.assign(document.querySelector('[data-testid=login-submit]').style, {position: 'relative', top: '80px'});
      }, true); }""")
    page.get_by_test_id("login-submit").click()
    assert page.evaluate("() => [window.__clicked, window.__stray, !!document.getElementById('shift')]") == [1, 0, True]
    page.get_by_test_id("login-password").fill("typed")
    assert page.get_by_test_id("login-password").evaluate("(e) => e.value") == "typed"
    page.evaluate("() => console.error('seen by the recorder')")
    assert "seen by the recorder" in rec.console_errors
    with pytest.raises(FirefoxError, match="no touch"):
        ff_pages(390, 844, has_touch=True, is_mobile=True)


# --- first, while the fleet is exactly FLEET where it started: the live fleet view, item 9 (keyboard),
# item 11 (online first, hide offline)
def test_fleet_view_shows_every_robot_live(server, fleet, ff_pages):
    test_dashboard.test_fleet_view_shows_every_robot_live(server, fleet, ff_pages)


def test_keyboard_only_operator_sorts_selects_and_opens_a_robot(server, fleet, ff_pages):
    test_console_a11y.test_keyboard_only_operator_sorts_selects_and_opens_a_robot(server, fleet, ff_pages)


# item 9: axe-core on every page, before any other robot went offline (it waits for the one offline event)
def test_axe_finds_no_serious_violations_on_any_page(server, fleet, spawn_agent, ff_pages):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_console_a11y.test_axe_finds_no_serious_violations_on_any_page(
            server, fleet, spawn, ff_pages, None, "light"
        )


def test_online_robots_first_and_hide_offline_is_remembered(server, fleet, spawn_agent, ff_pages):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_console_layout.test_online_robots_first_and_hide_offline_is_remembered(
            server, fleet, spawn, ff_pages, None
        )


# --- item 7: the command log (before any other test sends a command)
def test_holds_collapse_into_one_row_and_the_log_survives_a_reload(server, spawn_agent, ff_pages):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_command_log.test_holds_collapse_into_one_row_and_the_log_survives_a_reload(server, spawn, ff_pages)


def test_a_pause_longer_than_the_deadman_starts_a_new_row(server, ff_pages):
    test_command_log.test_a_pause_longer_than_the_deadman_starts_a_new_row(server, ff_pages)


# --- driving (the fleet's robots move from here on): hold to drive, keys, the e-stop for every robot
def test_hold_button_drives_and_release_stops(server, fleet, ff_pages):
    test_dashboard.test_hold_button_drives_and_release_stops(server, fleet, ff_pages)


def test_keyboard_turns_while_held_and_space_stops(server, fleet, ff_pages):
    test_dashboard.test_keyboard_turns_while_held_and_space_stops(server, fleet, ff_pages)


def test_estop_stops_every_robot_and_release_restores_driving(server, fleet, ff_pages):
    test_dashboard.test_estop_stops_every_robot_and_release_restores_driving(server, fleet, ff_pages)


# --- item 6: the robot table at 1280x720 with camera robots; item 12: the e-stop bar, the robot page
# without a camera, the IMU chart's labels
def test_robot_table_is_not_clipped_at_1280x720_with_cameras(server, fleet, spawn_agent, ff_pages):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_console_layout.test_robot_table_is_not_clipped_at_1280x720_with_cameras(server, fleet, spawn, ff_pages)


def test_estop_bar_names_who_pressed_it_and_moves_nothing(server, fleet, ff_pages):
    test_console_layout.test_estop_bar_names_who_pressed_it_and_moves_nothing(server, fleet, ff_pages, None)


def test_robot_without_camera_gets_no_black_box_and_imu_labels_fit(server, fleet, spawn_agent, ff_pages):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_console_layout.test_robot_without_camera_gets_no_black_box_and_imu_labels_fit(
            server, fleet, spawn, ff_pages, None
        )


# --- alarms, and forgetting a gone robot (item 11)
def test_alarm_banner_appears_and_acknowledge_works(server, mqtt_probe, ff_pages):
    test_alarm_banner.test_alarm_banner_appears_and_acknowledge_works(server, mqtt_probe, ff_pages)


def test_an_admin_forgets_a_gone_robot_from_its_page(server, mqtt_probe, ff_pages):
    test_alarm_banner.test_an_admin_forgets_a_gone_robot_from_its_page(server, mqtt_probe, ff_pages)


# --- item 9: contrast
def test_offline_grey_and_stale_amber_meet_wcag_aa_in_the_light_theme(server, spawn_agent, ff_pages):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_console_a11y.test_offline_grey_and_stale_amber_meet_wcag_aa_in_the_light_theme(server, spawn, ff_pages)


# --- item 4: reasons inline, not in hover tooltips (a viewer in a phone-sized window, with the mouse)
def test_reasons_show_inline(server, fleet, firefox, spawn_agent, tmp_path):
    pages = FirefoxPages(firefox, server, touch_as_mouse=True)
    try:
        with _forgotten_after(server, spawn_agent) as spawn:
            test_console_touch.test_reasons_show_inline_on_touch(server, fleet, pages, spawn, tmp_path)
    finally:
        pages.close()


# --- holds, the control lease between two operators, the deadman when the tab closes
def test_hold_this_robot_from_its_page_refuses_driving_until_released(server, fleet, ff_pages):
    test_drive_deadman.test_hold_this_robot_from_its_page_refuses_driving_until_released(server, fleet, ff_pages)


def test_driven_by_request_and_grant_between_two_operators(server, fleet, ff_pages):
    test_control_lease.test_driven_by_request_and_grant_between_two_operators(server, fleet, ff_pages.as_browser())


def test_the_fleet_map_shows_a_running_mission_as_the_server_pushes_it(server, spawn_agent, mqtt_probe, ff_pages):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_missions_panel.test_the_fleet_map_panel_shows_the_mission_and_acts_without_moving_the_layout(
            server, spawn, mqtt_probe, ff_pages, None
        )


def test_the_missions_page_from_the_drawn_area_to_the_report_and_its_run(server, spawn_agent, mqtt_probe, ff_pages):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_missions_panel.test_draw_start_watch_coverage_abort(server, spawn, mqtt_probe, ff_pages)


@pytest.mark.realtime  # a wall-clock safety bound, as its Chromium twin: the realtime lane, alone (0.524 s in the
# loaded browser lane of a clean-clone run)
def test_closing_the_tab_while_holding_stops_the_robot(server, fleet, ff_pages):
    test_drive_deadman.test_closing_the_tab_while_holding_stops_the_robot(server, fleet, ff_pages)


# --- item 2: /docs renders (Swagger UI 5) and "Try it out" runs GET /api/robots
def test_api_docs_render_and_try_it_out_runs(server, spawn_agent, ff_pages):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_console_layout.test_api_docs_render_and_try_it_out_runs(server, spawn, ff_pages, None)


# --- issue 29 #9: every page under the Content-Security-Policy (the camera, a run's replay, exports, axe, /docs)
def test_every_page_works_under_the_content_security_policy(server, spawn_agent, ff_pages, tmp_path):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_content_security_policy.test_every_page_works_under_the_content_security_policy(
            server, spawn, ff_pages, tmp_path
        )


# --- item 3: Users & tokens
def test_admin_manages_users_and_tokens(server, ff_pages):
    test_users_page.test_admin_manages_users_and_tokens(server, ff_pages)


def test_a_non_admin_sees_why_the_users_page_is_not_for_them(server, ff_pages):
    test_users_page.test_a_non_admin_sees_why_the_users_page_is_not_for_them(server, ff_pages)


# --- item 8: history as a research tool (an hour of stored telemetry)
def test_an_hour_exports_every_stored_point_and_a_bucketed_export_says_so(hour, ff_pages, tmp_path):
    test_history_research.test_an_hour_exports_every_stored_point_and_a_bucketed_export_says_so(
        hour, ff_pages, tmp_path
    )


def test_history_plots_robots_fields_bands_gaps_units_tags_and_trajectories(hour, server, ff_pages):
    test_history_research.test_history_plots_robots_fields_bands_gaps_units_tags_and_trajectories(
        hour, server, ff_pages
    )


def test_history_chart_and_csv_export_hold_the_stored_points(server, spawn_agent, ff_pages, tmp_path):
    test_robot_and_history.test_history_chart_and_csv_export_hold_the_stored_points(
        server, spawn_agent, ff_pages, tmp_path
    )


# --- issue 26: nothing moves under a finger (no touch emulation here: the phone's and tablet's sizes with a mouse)
@pytest.mark.parametrize("view", ["phone", "tablet", "laptop"])
def test_controls_stay_put_while_robots_come_online_and_alarms_come_and_go(
    server, spawn_agent, mqtt_probe, ff_pages, view
):
    with _forgotten_after(server, spawn_agent) as spawn:
        test_nothing_moves.test_controls_stay_put_while_robots_come_online_and_alarms_come_and_go(
            server, spawn, mqtt_probe, ff_pages, view, touch=False
        )


# --- last: the server restarts in this one (item 9: the connection lost and restored are announced)
def test_drive_buttons_have_names_and_changes_are_announced(server, fleet, ff_pages):
    test_console_a11y.test_drive_buttons_have_names_and_changes_are_announced(server, fleet, ff_pages)
