"""The Audit page (admins), in a real Chromium against a real server: the trail of real actions (user and
token changes, e-stops) newest first, filters by action, actor and time range, older pages, and a CSV
export of everything the filters match; a non-admin sees why the page is not for them."""

from __future__ import annotations

import csv
import io
import json
from datetime import datetime
from typing import Any

from tests.frontend.console_support import answer_held, axe_violations, open_page, wait_held
from tests.support.procs import wait_for

ESTOPS = 60  # 60 engage + 60 release: more than one page (100) of the trail


def _rows(page) -> list[str]:
    return page.locator("[data-testid=audit-row]").evaluate_all("rows => rows.map(r => r.dataset.action)")


def test_admin_reads_filters_pages_and_exports_the_trail(server, page_factory, tmp_path):
    page, rec = open_page(page_factory, "/")  # its admin user is created (and audited) first
    with server.client() as c:
        before = len(c.get("/api/audit", params={"limit": 1000}).json())
        r = c.post("/api/users", json={"username": "uma", "password": "uma-password-1", "role": "viewer"})
        assert r.status_code == 201
        assert c.patch("/api/users/uma", json={"role": "operator"}).status_code == 200
        token = c.post("/api/tokens", json={"name": "lab-script", "role": "operator"}).json()
        with server.client(token["token"]) as op:
            for _ in range(ESTOPS):
                assert op.post("/api/estop", json={"reason": "drill"}).status_code == 202
                assert op.post("/api/estop/release", json={}).status_code == 202
        assert c.delete(f"/api/tokens/{token['id']}").status_code == 204
        total = before + 3 + 2 * ESTOPS + 1
        wait_for(lambda: len(c.get("/api/audit", params={"limit": 1000}).json()) == total, 10, what="the trail")
        newest_ts = c.get("/api/audit", params={"limit": 1}).json()[0]["ts"]

    page.get_by_test_id("nav-audit").click()
    page.wait_for_url("**/audit")
    page.locator("[data-testid=audit-row]").first.wait_for()

    # newest first, one page of 100, and the older ones on request
    first = _rows(page)
    assert len(first) == 100 and first[0] == "token_revoke" and first[1] == "estop_release"
    page.get_by_test_id("audit-more").click()
    wait_for(lambda: len(_rows(page)) == total, 5, what="the older entries")
    assert _rows(page)[-before - 3 : len(_rows(page)) - before] == ["token_create", "user_update", "user_create"]
    assert page.get_by_test_id("audit-more").is_hidden()
    row = page.locator("[data-testid=audit-row][data-action=user_update]")
    assert "user: uma" in row.inner_text() and "role: operator" in row.inner_text()

    # filters: by action, by actor (the token's name), and a time range that ends before everything
    page.get_by_test_id("audit-action").fill("estop")
    page.get_by_test_id("audit-apply").click()
    wait_for(lambda: set(_rows(page)) == {"estop"}, 5, what="only e-stops")
    assert len(_rows(page)) == ESTOPS
    page.get_by_test_id("audit-action").fill("")
    page.get_by_test_id("audit-actor").fill("lab-script")
    page.get_by_test_id("audit-apply").click()
    wait_for(lambda: set(_rows(page)) == {"estop", "estop_release"}, 5, what="only the token's actions")
    page.get_by_test_id("audit-actor").fill("")
    page.get_by_test_id("audit-end").fill("2020-01-01T00:00:00")
    page.get_by_test_id("audit-apply").click()
    wait_for(lambda: _rows(page) == [], 5, what="nothing before 2020")
    after = datetime.fromtimestamp(newest_ts + 3600).strftime("%Y-%m-%dT%H:%M:%S")
    page.get_by_test_id("audit-end").fill(after)
    page.get_by_test_id("audit-action").fill("user_update")
    page.get_by_test_id("audit-apply").click()
    wait_for(lambda: _rows(page) == ["user_update"], 5, what="the role change within the range")

    # CSV: every entry the filters match, with its detail as JSON
    page.get_by_test_id("audit-action").fill("")
    page.get_by_test_id("audit-end").fill("")
    page.get_by_test_id("audit-apply").click()
    with page.expect_download() as dl:
        page.get_by_test_id("audit-csv").click()
    path = tmp_path / "audit.csv"
    dl.value.save_as(path)
    rows = list(csv.DictReader(io.StringIO(path.read_text())))
    assert len(rows) == total
    assert list(rows[0]) == [
        "id",
        "ts",
        "time_utc",
        "actor",
        "actor_name",
        "token_id",
        "client",
        "action",
        "robot_id",
        "detail",
    ]
    assert rows[0]["action"] == "token_revoke" and json.loads(rows[0]["detail"]) == {"token": token["id"]}
    assert [r["action"] for r in rows].count("estop") == ESTOPS
    assert all(r["token_id"] == token["id"] for r in rows if r["action"] == "estop")
    page.get_by_test_id("audit-status").filter(has_text=f"Exported {total} audit entries").wait_for()

    assert axe_violations(page) == []
    assert rec.failures == [], rec.failures
    assert rec.console_errors == [], rec.console_errors


def test_a_non_admin_sees_why_the_audit_page_is_not_for_them(server, page_factory):
    with server.client() as c:
        assert (
            c.post("/api/users", json={"username": "otis", "password": "operator-pass", "role": "operator"}).status_code
            == 201
        )
    page, rec = page_factory(logged_in=False)
    page.goto("/login?next=/audit")
    page.get_by_test_id("login-username").fill("otis")
    page.get_by_test_id("login-password").fill("operator-pass")
    page.get_by_test_id("login-password").press("Enter")
    page.wait_for_url("**/audit")
    note = page.get_by_test_id("audit-denied")
    note.wait_for()
    assert "for admins (you are operator)" in note.inner_text()
    assert page.get_by_test_id("nav-audit").is_hidden()
    assert page.get_by_test_id("audit-csv").is_disabled()
    assert [f for f in rec.failures if not f.startswith("401")] == [], rec.failures  # it never asked the admin API


def test_the_status_says_what_the_last_action_did(server, page_factory, tmp_path):
    """Apply, then CSV at once: the export can end before the Apply's reply comes (a loaded server answered
    them so). The status must then still say what was exported, not the rows the late reply shows."""
    page, _ = open_page(page_factory, "/audit")
    page.locator("[data-testid=audit-row]").first.wait_for()
    held: list[Any] = []
    page.route(
        lambda url: "/api/audit?" in url and "action=estop" in url,  # only the Apply below asks for e-stops
        lambda route: held.append(route),
    )
    page.get_by_test_id("audit-action").fill("estop")
    page.get_by_test_id("audit-apply").click()
    wait_held(page, held, 1, "filtered loads")
    page.get_by_test_id("audit-action").fill("")
    with page.expect_download() as dl:
        page.get_by_test_id("audit-csv").click()
    dl.value.save_as(tmp_path / "audit.csv")
    exported = page.get_by_test_id("audit-status").filter(has_text="Exported")
    exported.wait_for()
    answer_held(page, held[0], "[]", "action=estop")  # the Apply's reply comes last
    assert exported.is_visible(), page.get_by_test_id("audit-status").inner_text()
