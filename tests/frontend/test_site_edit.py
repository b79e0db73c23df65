"""An admin edits the site in Chromium (real server and broker): the new boundary is a new version that the
map draws and GET /api/site serves; a self-intersecting boundary is refused inline with its code, and
nothing changes. A viewer sees the version in force but no form."""

from __future__ import annotations

import json

from tests.backend.api.conftest import new_token

NEW = [[-1.5, -1.0], [1.5, -1.0], [1.5, 1.2], [-1.5, 1.2]]
BOWTIE = [[0, 0], [1, 1], [1, 0], [0, 1]]


def _outline(page) -> list[list[float]]:
    return page.evaluate("""() => { const t = document.getElementById('fleet-map').data
        .find((d) => d.name === 'pool outline'); return [Array.from(t.x), Array.from(t.y)]; }""")


def test_an_admin_changes_the_boundary_and_the_map_and_the_api_show_the_new_version(server, page_factory):
    with server.client() as c:
        before = c.get("/api/site").json()
    page, rec = page_factory()
    page.goto("/")
    status = page.get_by_test_id("site-line")
    status.filter(has_text=f"Site v{before['version']}").wait_for(timeout=15000)
    page.get_by_text("Edit site").click()
    assert json.loads(page.get_by_test_id("site-boundary").input_value()) == before["boundary"]

    # a boundary that crosses itself: refused inline with the server's code, nothing changes
    page.get_by_test_id("site-boundary").fill(json.dumps(BOWTIE))
    page.get_by_test_id("site-save").click()
    error = page.get_by_test_id("site-error")
    error.wait_for(state="visible", timeout=10000)
    assert "bad_polygon" in error.inner_text() and "boundary" in error.inner_text()
    with server.client() as c:
        assert c.get("/api/site").json()["version"] == before["version"]
    # text that is not JSON is named before anything is sent
    page.get_by_test_id("site-keepouts").fill("[[oops")
    page.get_by_test_id("site-save").click()
    page.wait_for_function("() => document.querySelector('[data-testid=site-error]').textContent.includes('keepouts')")
    page.get_by_test_id("site-keepouts").fill("[]")

    # the new boundary, and the robots' safety filter changed with it: a new version, drawn on the map, served by
    # the API (what the form shows first is what the server holds)
    assert page.get_by_test_id("site-avoidance").is_checked() == before["avoidance"]["enabled"]
    assert float(page.get_by_test_id("site-avoid-margin").input_value()) == before["avoidance"]["margin_m"]
    page.get_by_test_id("site-boundary").fill(json.dumps(NEW))
    page.get_by_test_id("site-separation").fill("0.4")
    page.get_by_test_id("site-avoid-margin").fill("0.05")
    page.get_by_test_id("site-creep").fill("0.02")
    page.get_by_test_id("site-avoidance").uncheck()
    page.get_by_test_id("site-save").click()
    version = before["version"] + 1
    status.filter(has_text=f"Site v{version}").wait_for(timeout=10000)
    assert page.get_by_test_id("site-error").is_hidden()
    page.wait_for_function(f"() => window.fleetDebug.mapSite()?.version === {version}", timeout=10000)
    ring = [*NEW, NEW[0]]
    page.wait_for_function(
        """(xs) => { const t = document.getElementById('fleet-map').data.find((d) => d.name === 'pool outline');
        return t && JSON.stringify(Array.from(t.x)) === JSON.stringify(xs); }""",
        arg=[p[0] for p in ring],
        timeout=10000,
    )
    assert _outline(page) == [[p[0] for p in ring], [p[1] for p in ring]]
    with server.client() as c:
        site = c.get("/api/site").json()
        assert site["version"] == version and site["boundary"] == NEW and site["source"] == "api"
        assert site["min_separation_m"] == 0.4
        assert site["avoidance"] == {"enabled": False, "margin_m": 0.05, "creep_mps": 0.02}
    # a reload draws the stored version
    page.reload()
    page.wait_for_function(f"() => window.fleetDebug?.mapSite()?.version === {version}", timeout=15000)
    # the one refused PUT is the browser's own log line; nothing else went wrong
    others = [e for e in rec.console_errors if "status of 422" not in e]
    assert others == [] and len(rec.console_errors) == 1, rec.console_errors


def test_a_viewer_sees_the_version_but_no_form(server, page_factory, browser):
    token = new_token(server, "viewer")
    ctx = browser.new_context(base_url=server.base_url, extra_http_headers={"Authorization": f"Bearer {token}"})
    try:
        page = ctx.new_page()
        page.goto("/")
        page.get_by_test_id("site-line").filter(has_text="Site v").wait_for(timeout=15000)
        page.wait_for_function("() => window.fleetDebug?.me()?.role === 'viewer'", timeout=10000)
        assert page.get_by_test_id("site-edit").is_hidden()
    finally:
        ctx.close()
