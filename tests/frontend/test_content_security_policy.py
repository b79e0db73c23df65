"""The Content-Security-Policy (issue 29 #9; set in one place, backend/core/headers.py) in a real browser:
every page of the dashboard, the login page and the API docs carry it and do their work under it (the camera
shows frames, the WebGL and 3-D charts draw, exports download, axe runs, Swagger renders) with not one
violation, after the test has first shown that a violation on the same site is caught. Chromium here; the
same function runs in Firefox ESR (test_firefox_console.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from backend.core.headers import CONTENT_SECURITY_POLICY
from tests.backend.helpers import wait_robot
from tests.frontend.console_support import axe_violations, open_page

#: What the policy refuses, done by the page itself: an inline script, an inline <style>, a style attribute
#: set as markup, and a string made code (eval). Each is a violation the reporter must see
#: (tests/frontend/conftest.py: CSP_REPORTER), and none may take effect.
_FORBIDDEN = """() => {
  const script = document.createElement('script');
  script.textContent = 'window.__inlineRan = true;';
  document.head.append(script);
  const style = document.createElement('style');
  style.textContent = 'body { outline: 3px solid rgb(255, 0, 0); }';
  document.head.append(style);
  const marked = document.createElement('p');
  marked.id = 'csp-marked';
  marked.setAttribute('style', 'color: rgb(255, 0, 0)');
  document.body.append(marked);
  setTimeout('window.__evalRan = true;', 0);
}"""
_FORBIDDEN_DIRECTIVES = {"script-src-elem", "style-src-elem", "style-src-attr", "script-src"}
_TOOK_EFFECT = """() => ({inline: window.__inlineRan ?? false, eval: window.__evalRan ?? false,
  style: getComputedStyle(document.body).outlineColor === 'rgb(255, 0, 0)'
    && getComputedStyle(document.body).outlineStyle === 'solid',
  attr: getComputedStyle(document.getElementById('csp-marked')).color === 'rgb(255, 0, 0)'})"""
_NOTHING_TOOK_EFFECT = {"inline": False, "eval": False, "style": False, "attr": False}
_POLICY_OF_PAGE = "async () => (await fetch(location.href)).headers.get('content-security-policy')"


def _violations(page: Any) -> list[str]:
    return list(page.evaluate("() => window.__cspViolations"))


def _caught(page: Any, rec: Any) -> None:
    """A page of this site that breaks the policy: every breach is refused, seen and made a console error
    (so the checks below, and every browser test's ``console_errors == []``, can fail)."""
    page.evaluate(_FORBIDDEN)
    page.wait_for_function(f"() => window.__cspViolations.length >= {len(_FORBIDDEN_DIRECTIVES)}")
    seen = _violations(page)
    assert {v.split()[2] for v in seen} == _FORBIDDEN_DIRECTIVES, seen
    assert page.evaluate(_TOOK_EFFECT) == _NOTHING_TOOK_EFFECT
    assert [e for e in rec.console_errors if e.startswith("CSP violation")] == seen


def _clean(page: Any, what: str) -> None:
    """The page as it is now holds the site's policy and broke none of it."""
    assert page.evaluate(_POLICY_OF_PAGE) == CONTENT_SECURITY_POLICY, what
    assert _violations(page) == [], what


def _downloaded(page: Any, button: str, path: Path) -> str:
    """Press an export button; the file the browser was handed, as text."""
    with page.expect_download() as dl:
        page.get_by_test_id(button).click()
    dl.value.save_as(path)
    return path.read_text()


def _go(page: Any, path: str) -> None:
    """To ``path`` by the dashboard's own routing, as the back button goes: one page load serves every view."""
    page.evaluate("(p) => { history.pushState({}, '', p); dispatchEvent(new PopStateEvent('popstate')); }", path)


def _every_view(page: Any, server: Any, run_id: int, tmp_path: Path) -> None:
    """Each view of the dashboard at work, the policy unbroken after each."""
    # the fleet: the map's WebGL (scattergl) layers, with Plotly's styles from vendor/plotly.css, not a <style>
    page.get_by_test_id("robot-row-cam-1").wait_for()
    page.wait_for_function("() => 'cam-1' in window.fleetDebug.mapRobots()")
    assert page.evaluate("() => getComputedStyle(document.querySelector('#fleet-map .main-svg')).position") == (
        "absolute"
    )
    _clean(page, "/")
    # a robot's page: camera frames (the camera WebSocket) with the tag overlay, the WebGL charts and the 3-D view
    _go(page, "/robots/cam-1")
    page.wait_for_function("() => window.fleetDebug.camera().frames >= 5", timeout=20000)
    page.wait_for_function("() => window.fleetDebug.camera().overlays >= 1", timeout=10000)
    page.wait_for_function("() => document.getElementById('chart-xyz').data?.[0]?.x.length > 5", timeout=10000)
    page.wait_for_function("() => document.querySelector('#chart-3d .gl-container canvas')")
    _clean(page, "/robots/cam-1")
    with server.client() as c:  # the run has recorded the camera robot meanwhile
        assert c.post(f"/api/runs/{run_id}/stop").status_code == 200
        run = c.get(f"/api/runs/{run_id}").json()
    start, end = run["started_at"] - 30, run["ended_at"] + 1
    # history: a time series and an x-y trajectory (WebGL lines and markers, a colour bar), a CSV export
    _go(page, f"/history?robots=cam-1&stream=position&start={start:.0f}&end={end:.0f}&field=x")
    page.wait_for_function("() => document.getElementById('history-chart').data?.[0]?.x.length > 3", timeout=15000)
    csv = _downloaded(page, "export-csv", tmp_path / "history.csv")
    assert "cam-1" in csv and len(csv.splitlines()) > 3, csv[:300]
    _go(page, f"/history?robots=cam-1&stream=position&start={start:.0f}&end={end:.0f}&mode=xy")
    page.wait_for_function(
        "() => document.getElementById('history-chart').data?.some((t) => t.meta?.kind === 'trajectory')"
    )
    page.wait_for_function("() => document.querySelector('#history-chart .colorbar')")
    _clean(page, "/history")
    # runs: the list, and a run's replay on its own map
    _go(page, "/runs")
    page.get_by_test_id("run-link").first.wait_for()
    _clean(page, "/runs")
    _go(page, f"/runs/{run_id}")
    page.wait_for_function("() => document.querySelector('[data-testid=replay-map]')?.dataset.t")
    _clean(page, f"/runs/{run_id}")
    # missions (its form sets styles), users and tokens, the audit trail and its CSV export
    _go(page, "/missions")
    page.get_by_test_id("mission-map").wait_for()
    page.get_by_test_id("mission-width").wait_for()
    _clean(page, "/missions")
    _go(page, "/users")
    page.locator("[data-testid=user-rows] tr").first.wait_for()
    _clean(page, "/users")
    _go(page, "/audit")
    page.wait_for_function("() => document.querySelector('[data-testid=audit-status]')?.textContent.includes('shown')")
    assert _downloaded(page, "audit-csv", tmp_path / "audit.csv").startswith("id,"), "the audit CSV's header"
    _clean(page, "/audit")


@pytest.mark.slow
def test_every_page_works_under_the_content_security_policy(server, spawn_agent, page_factory, tmp_path):
    spawn_agent("cam-1", "--camera", "--start-pose=1,0,0")  # faces tag 0 on the east wall, 1 m away
    with server.client() as c:
        wait_robot(c, "cam-1", lambda r: "camera" in r["capabilities"]["sensors"] and r["position"], timeout=30)
        started = c.post("/api/runs", json={"name": "csp", "robots": ["cam-1"]})
        assert started.status_code == 201, started.text
        run_id = started.json()["id"]

    # first, that it can fail: a page of the site breaking the policy is caught, and nothing of it runs
    anon, anon_rec = page_factory(logged_in=False)
    anon.goto("/login")
    anon.get_by_test_id("login-username").wait_for()
    _caught(anon, anon_rec)
    # the login page itself, with axe run in it (evaluated: the policy refuses the inline <script> it was)
    anon.goto("/login")
    anon.get_by_test_id("login-username").wait_for()
    assert axe_violations(anon) == []
    _clean(anon, "/login")

    page, rec = open_page(page_factory, "/")
    _every_view(page, server, run_id, tmp_path)
    # the API docs: Swagger UI started by a file of its own (no inline script), its icons data: images
    page.goto("/docs")
    page.locator(".swagger-ui .info .title", has_text="Mollusca Fleet").wait_for(timeout=20000)
    page.locator(".opblock-summary-path").first.wait_for()
    _clean(page, "/docs")
    assert rec.console_errors == [], rec.console_errors
    with server.client() as c:  # the Firefox module's server goes on to other tests
        assert c.delete(f"/api/runs/{run_id}").status_code == 204
