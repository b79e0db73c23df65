"""The Users & tokens page (issue 21, item 3), in a real Chromium against a real server: an admin creates
a user (the generated password is shown once and logs in), changes the role, disables (their session
ends) and re-enables, resets the password (the old one stops working); creates an API token (shown once,
it authenticates) and revokes it (it stops working). The API's refusals show inline; an admin cannot lock
out their own account; a non-admin sees why the page is not for them; every change is in the server log
with the admin who made it."""

from __future__ import annotations

import httpx
import pytest

from tests.frontend.console_support import axe_violations, inside_viewport, no_horizontal_overflow, open_page
from tests.support.procs import wait_for


def _login(server, username: str, password: str) -> httpx.Response:
    with server.client(anonymous=True) as c:
        return c.post("/api/auth/login", json={"username": username, "password": password})


def _shown_once(page, what: str) -> str:
    """The secret in the shown-once box, once the box is about ``what``."""
    page.get_by_test_id("shown-once").filter(has_text=what).wait_for()
    return page.get_by_test_id("shown-once-value").inner_text().strip()


def test_admin_manages_users_and_tokens(server, page_factory):
    page, rec = open_page(page_factory, "/")
    page.get_by_test_id("nav-users").click()
    page.wait_for_url("**/users")
    page.locator("[data-testid=user-browser-admin]").wait_for()

    # create a user with a generated password: shown once, and it logs in with the chosen role
    page.get_by_test_id("new-user-name").fill("otto")
    page.get_by_test_id("new-user-role").select_option("operator")
    page.get_by_test_id("create-user").click()
    password = _shown_once(page, "Password of otto")
    assert len(password) >= 12
    r = _login(server, "otto", password)
    assert r.status_code == 200 and r.json()["role"] == "operator", r.text
    session = r.cookies["fleet_session"]
    page.locator("[data-testid=user-otto][data-role=operator]").wait_for()

    # the API's refusals show inline: a duplicate name, a too short password
    page.get_by_test_id("new-user-name").fill("otto")
    page.get_by_test_id("new-user-password").fill("secret-password")
    page.get_by_test_id("create-user").click()
    page.get_by_test_id("user-form-error").filter(has_text="exists").wait_for()
    page.get_by_test_id("new-user-name").fill("short")
    page.get_by_test_id("new-user-password").fill("abc")
    page.get_by_test_id("create-user").click()
    too_short = "password: String should have at least 8 characters"  # the field, in words, not JSON
    page.get_by_test_id("user-form-error").filter(has_text=too_short).wait_for()

    # change the role
    page.get_by_test_id("role-otto").select_option("viewer")
    page.locator("[data-testid=user-otto][data-role=viewer]").wait_for()
    with server.client(anonymous=True) as c:
        c.cookies.set("fleet_session", session)
        assert c.get("/api/auth/me").json()["role"] == "viewer"  # applies at once to the open session

        # disable: a first press only arms; the second disables and ends the session
        page.get_by_test_id("disable-otto").click()
        assert page.get_by_test_id("disable-otto").inner_text() == "Tap again to disable"
        assert c.get("/api/auth/me").status_code == 200
        page.get_by_test_id("disable-otto").click()
        page.locator("[data-testid=user-otto][data-disabled=true]").wait_for()
        assert c.get("/api/auth/me").status_code == 401
    assert _login(server, "otto", password).status_code == 401
    page.get_by_test_id("enable-otto").click()
    page.locator("[data-testid=user-otto][data-disabled=false]").wait_for()
    assert _login(server, "otto", password).status_code == 200

    # reset the password: the new one is shown once, the old one stops working
    page.get_by_test_id("reset-otto").click()
    page.get_by_test_id("reset-otto").click()
    page.get_by_test_id("users-status").filter(has_text="Password of otto reset").wait_for()
    new_password = _shown_once(page, "New password of otto")
    assert new_password != password
    assert _login(server, "otto", password).status_code == 401
    assert _login(server, "otto", new_password).status_code == 200

    # my own account: no disabling or demoting here, and the row says why
    assert page.get_by_test_id("disable-browser-admin").is_disabled()
    assert page.get_by_test_id("role-browser-admin").is_disabled()
    assert "another admin" in page.locator("[data-testid=user-browser-admin] [data-testid=self-note]").inner_text()

    # an API token: shown once, it authenticates with its role; revoked, it stops working
    page.get_by_test_id("new-token-name").fill("nightly-run")
    page.get_by_test_id("new-token-role").select_option("operator")
    page.get_by_test_id("new-token-days").fill("2")
    page.get_by_test_id("create-token").click()
    token = _shown_once(page, "Token nightly-run")
    assert token.startswith("flt_")
    with server.client(token) as c:
        me = c.get("/api/auth/me").json()
        assert (me["role"], me["name"], me["kind"]) == ("operator", "nightly-run", "token"), me
    page.locator("[data-testid=token-nightly-run][data-revoked=false]").wait_for()
    page.get_by_test_id("done-hide").click()
    assert page.get_by_test_id("shown-once").is_hidden()  # gone from the page
    assert token not in page.content()
    page.get_by_test_id("new-token-name").fill("bad-expiry")
    page.get_by_test_id("new-token-days").fill("-1")
    page.get_by_test_id("create-token").click()
    page.get_by_test_id("token-form-error").filter(has_text="positive number").wait_for()
    page.get_by_test_id("revoke-nightly-run").click()
    page.get_by_test_id("revoke-nightly-run").click()
    page.locator("[data-testid=token-nightly-run][data-revoked=true]").wait_for()
    with server.client(token) as c:
        assert c.get("/api/auth/me").status_code == 401

    assert axe_violations(page) == []
    assert [f for f in rec.failures if not f.startswith(("409", "422"))] == [], rec.failures
    assert rec.console_errors == [] or all(e.startswith("Failed to load resource") for e in rec.console_errors)

    # audited: each change names the admin who made it
    def audit_log() -> str | None:
        out = server.output()
        return out if "revoked by browser-admin" in out else None

    log = wait_for(audit_log, 5, what="the audit lines in the server log")
    for line in (
        "user otto (operator) created by browser-admin",
        "user otto changed (role viewer) by browser-admin",
        "user otto changed (disabled) by browser-admin",
        "user otto changed (new password) by browser-admin",
        "revoked by browser-admin",
    ):
        assert line in log, line


def test_the_api_refuses_an_admin_locking_out_their_own_account(server):
    with server.client() as c:
        r = c.post("/api/users", json={"username": "ada", "password": "ada-password-1", "role": "admin"})
        assert r.status_code == 201, r.text
    with server.client(anonymous=True) as c:
        assert c.post("/api/auth/login", json={"username": "ada", "password": "ada-password-1"}).status_code == 200
        for body, what in (({"disabled": True}, "disable"), ({"role": "operator"}, "demote")):
            r = c.patch("/api/users/ada", json=body)
            assert r.status_code == 409 and f"cannot {what} your own account" in r.json()["detail"], r.text
        r = c.delete("/api/users/ada")
        assert r.status_code == 409 and "cannot delete your own account" in r.json()["detail"]
        assert c.patch("/api/users/ada", json={"password": "ada-password-2"}).status_code == 200  # allowed
        assert c.get("/api/users/ada").status_code == 401  # a new password ends the session (as before)
    with server.client() as c:  # another admin can
        assert c.patch("/api/users/ada", json={"role": "operator"}).json()["role"] == "operator"


def test_a_non_admin_sees_why_the_users_page_is_not_for_them(server, page_factory):
    with server.client() as c:
        r = c.post("/api/users", json={"username": "olga", "password": "operator-pass", "role": "operator"})
        assert r.status_code == 201, r.text
    page, rec = page_factory(logged_in=False)
    page.goto("/login?next=/users")
    page.get_by_test_id("login-username").fill("olga")
    page.get_by_test_id("login-password").fill("operator-pass")
    page.get_by_test_id("login-password").press("Enter")
    page.wait_for_url("**/users")
    note = page.get_by_test_id("users-denied")
    note.wait_for()
    assert "for admins (you are operator)" in note.inner_text()
    assert page.get_by_test_id("nav-users").is_hidden()
    assert page.get_by_test_id("create-user").is_disabled()
    assert [f for f in rec.failures if not f.startswith("401")] == [], rec.failures  # it never asked the admin API


@pytest.mark.parametrize("device", ["phone", "tablet"])
def test_users_page_works_with_touch(server, page_factory, device):
    """On a phone and a tablet: the menu leads to the page, a token is created with taps and shown once,
    fully on screen, and revoked with two taps."""
    page, _ = open_page(page_factory, "/", device)
    if device == "phone":
        page.get_by_test_id("nav-toggle").tap()
    page.get_by_test_id("nav-users").tap()
    page.wait_for_url("**/users")
    page.locator("[data-testid=user-browser-admin]").wait_for()
    no_horizontal_overflow(page)
    page.get_by_test_id("new-token-name").tap()
    page.keyboard.type("tablet-script")
    page.get_by_test_id("create-token").tap()
    token = _shown_once(page, "Token tablet-script")
    page.get_by_test_id("shown-once-value").scroll_into_view_if_needed()
    inside_viewport(page, "[data-testid=shown-once-value]")
    no_horizontal_overflow(page)
    with server.client(token) as c:
        assert c.get("/api/auth/me").json()["name"] == "tablet-script"
    page.get_by_test_id("revoke-tablet-script").tap()
    page.get_by_test_id("revoke-tablet-script").tap()
    page.locator("[data-testid=token-tablet-script][data-revoked=true]").wait_for()
    with server.client(token) as c:
        assert c.get("/api/auth/me").status_code == 401
