"""Keyboard and accessibility of the console (issue 21, item 9), in a real Chromium: axe-core finds no
serious or critical violation on any page (light theme, desktop, phone and tablet with touch); a
keyboard-only operator reaches the sort headers and robot rows with Tab and uses them with Enter/Space;
drive buttons have names; e-stop and connection changes are announced in live regions; every page has
an h1; offline grey and stale amber meet WCAG AA."""

from __future__ import annotations

import pytest

from tests.frontend.conftest import FLEET
from tests.frontend.console_support import (
    axe_violations,
    inside_viewport,
    no_horizontal_overflow,
    open_page,
    wait_list_render,
)

PAGES = ["/", "/robots/snail-1", "/history", "/users", "/audit"]


def _settle(page, path: str) -> None:
    """Wait for what each page draws after its data arrives (rows, charts, history form, users table, audit)."""
    if path == "/":
        page.get_by_test_id("robot-row-snail-1").wait_for()
        page.wait_for_function("() => document.querySelector('#fleet-map .main-svg')")
    elif path.startswith("/robots/"):
        page.wait_for_function("() => document.querySelector('#chart-imu .main-svg')")
    elif path == "/history":
        page.wait_for_function("() => document.querySelectorAll('[data-testid=history-robots] option').length >= 3")
    elif path == "/audit":
        page.locator("[data-testid=audit-row]").first.wait_for()
    else:
        page.locator("[data-testid=user-rows] tr").first.wait_for()


@pytest.mark.parametrize(
    ("device", "scheme"), [(None, "light"), ("phone", "light"), ("tablet", "light"), (None, "dark")]
)
@pytest.mark.slow
def test_axe_finds_no_serious_violations_on_any_page(server, fleet, spawn_agent, page_factory, device, scheme):
    gone = spawn_agent("gone-1", "--start-pose=0,0,0")
    page, rec = open_page(page_factory, "/", device, color_scheme=scheme)
    page.locator("[data-testid=robot-row-gone-1][data-online=true]").wait_for()
    gone.stop()  # an offline row (grey), an offline ack in the e-stop bar, and events enough to scroll
    page.locator("[data-testid=robot-row-gone-1][data-online=false]").wait_for(timeout=20000)
    page.locator("[data-testid=events] li[data-kind=offline]").wait_for(timeout=10000)
    for path in PAGES:
        page.goto(path)
        page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
        _settle(page, path)
        assert page.locator("h1:visible").count() == 1, f"{path}: one visible h1"
        assert axe_violations(page) == [], path
        no_horizontal_overflow(page)  # every page fits the phone's and the tablet's width
        inside_viewport(page, "[data-testid=estop]")  # and the E-STOP is in reach on each
    # while the e-stop is engaged (the bar, the latched button, Release)
    page.goto("/")
    _settle(page, "/")
    page.keyboard.press("Escape")
    page.get_by_test_id("estop-release").wait_for()
    page.locator("[data-testid=estop-acks] li.acked").first.wait_for()
    assert axe_violations(page) == [], "e-stop engaged"
    with server.client() as c:
        c.post("/api/estop/release", json={"source": "test"})
    # the login page too
    anon, _ = page_factory(logged_in=False, color_scheme="light")
    anon.goto("/login")
    anon.get_by_test_id("login-username").wait_for()
    assert anon.locator("h1:visible").count() == 1
    assert axe_violations(anon) == [], "/login"
    assert rec.console_errors == [], rec.console_errors


def _tab_to(page, predicate_js: str, limit: int = 60) -> None:
    for _ in range(limit):
        page.keyboard.press("Tab")
        if page.evaluate(f"() => {{ const e = document.activeElement; return Boolean({predicate_js}); }}"):
            return
    raise AssertionError(f"Tab never reached {predicate_js}")


def test_keyboard_only_operator_sorts_selects_and_opens_a_robot(server, fleet, page_factory):
    page, _ = open_page(page_factory, "/", color_scheme="light")
    for rid in FLEET:
        page.get_by_test_id(f"robot-row-{rid}").wait_for()
    # the "Robot" sort header is a Tab stop; Enter reverses the order, Space restores it
    _tab_to(page, "e.closest('th[data-sort=id]')")
    order = "() => [...document.querySelectorAll('#robot-rows tr')].map((r) => r.dataset.robotId)"
    assert page.evaluate(order) == sorted(FLEET)
    page.keyboard.press("Enter")
    page.wait_for_function(f"() => ({order})().join() === '{','.join(sorted(FLEET, reverse=True))}'")
    assert page.get_attribute("th[data-sort=id]", "aria-sort") == "descending"
    page.keyboard.press("Space")
    page.wait_for_function(f"() => ({order})().join() === '{','.join(sorted(FLEET))}'")
    # rows are Tab stops: Tab to snail-2, Space selects it (and does not send a drive "stop")
    _tab_to(page, "e.dataset.robotId === 'snail-2'")
    page.keyboard.press("Space")
    page.wait_for_function("() => window.fleetDebug.selected() === 'snail-2'")
    assert page.evaluate("() => window.fleetDebug.drive().sent") == 0
    # the list re-renders every second: the focus stays on the row
    wait_list_render(page)  # the list re-rendered at least once since the selection
    assert page.evaluate("() => document.activeElement.dataset.robotId") == "snail-2"
    # Enter on the selected row opens its page
    page.keyboard.press("Enter")
    page.wait_for_url("**/robots/snail-2")
    assert page.get_by_test_id("robot-title").inner_text() == "snail-2"


def _announced(page, region: str, text: str, timeout: float = 10000) -> None:
    page.wait_for_function(
        "([id, t]) => document.querySelector(`[data-testid=${id}]`).textContent.includes(t)",
        arg=[region, text],
        timeout=timeout,
    )


def test_drive_buttons_have_names_and_changes_are_announced(server, fleet, page_factory):
    page, _ = open_page(page_factory, "/")
    page.get_by_test_id("robot-row-snail-1").wait_for()
    for name in (
        "Drive forward (hold)",
        "Drive backward (hold)",
        "Turn left (hold)",
        "Turn right (hold)",
        "Stop this robot",
    ):
        assert page.locator("#drive-host").get_by_role("button", name=name).count() == 1, name
    page.goto("/robots/snail-1")
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    assert page.locator("#robot-drive-host").get_by_role("button", name="Drive forward (hold)").count() == 1
    alert = page.get_by_test_id("announce-alert")
    assert alert.get_attribute("aria-live") == "assertive"
    page.get_by_test_id("estop").click()
    _announced(page, "announce-alert", "E-stop engaged by browser-admin via ui")
    page.get_by_test_id("estop-release").click()
    page.get_by_test_id("estop-release").click()
    _announced(page, "announce-alert", "E-stop released by browser-admin")
    # the live connection drops (server restart) and comes back: both announced politely
    polite = page.get_by_test_id("announce-polite")
    assert polite.get_attribute("aria-live") == "polite"
    server.stop()
    _announced(page, "announce-polite", "connection lost")
    server.start()
    _announced(page, "announce-polite", "connection restored", timeout=20000)


def _contrast(page, selector: str) -> float:
    """WCAG contrast of the element's text colour against the first opaque background behind it."""
    return page.evaluate(
        """(sel) => {
          const e = document.querySelector(sel);
          const rgb = (c) => c.match(/[\\d.]+/g).map(Number);
          const f = (v) => { v /= 255; return v <= 0.03928 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4; };
          const lum = ([r, g, b]) => 0.2126 * f(r) + 0.7152 * f(g) + 0.0722 * f(b);
          let bgEl = e, bg;
          while (bgEl) {
            const c = rgb(getComputedStyle(bgEl).backgroundColor);
            if (c.length < 4 || c[3] > 0) { bg = c; break; }
            bgEl = bgEl.parentElement;
          }
          const a = lum(rgb(getComputedStyle(e).color)), b = lum(bg ?? [255, 255, 255]);
          return (Math.max(a, b) + 0.05) / (Math.min(a, b) + 0.05);
        }""",
        selector,
    )


def test_offline_grey_and_stale_amber_meet_wcag_aa_in_the_light_theme(server, spawn_agent, page_factory):
    gone = spawn_agent("gone-1", "--start-pose=0,0,0")
    page, _ = open_page(page_factory, "/", color_scheme="light")
    page.locator("[data-testid=robot-row-gone-1][data-online=true]").wait_for()
    gone.stop()  # the robot goes away: its row turns offline grey
    page.locator("[data-testid=robot-row-gone-1][data-online=false]").wait_for(timeout=20000)
    assert _contrast(page, "[data-testid=robot-row-gone-1] td") >= 4.5
    assert _contrast(page, "[data-testid=state-gone-1]") >= 4.5
    # the stale badge's amber, on the list panel (a robot whose telemetry stopped shows it)
    page.evaluate("""() => {
      const b = document.createElement('span');
      Object.assign(b, {className: 'badge stale', id: 'probe-stale', textContent: 'stale'});
      document.querySelector('.list-panel .panel-head').append(b); }""")
    assert _contrast(page, "#probe-stale") >= 4.5
