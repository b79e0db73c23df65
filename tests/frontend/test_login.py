"""Logging in through the login page in a real Chromium: redirect to /login, wrong password, the HttpOnly
session cookie, back to the page asked for, the role in the top bar, logout ending the session."""

from __future__ import annotations

from urllib.parse import urlsplit

from tests.support.procs import wait_for


def test_login_page_flow(server, page_factory):
    with server.client() as admin:
        r = admin.post("/api/users", json={"username": "vera", "password": "vera-password", "role": "viewer"})
        assert r.status_code == 201, r.text
    page, rec = page_factory(logged_in=False)

    page.goto("/history")
    page.wait_for_url("**/login?next=*")
    assert urlsplit(page.url).query == "next=%2Fhistory"

    page.get_by_test_id("login-username").fill("vera")
    page.get_by_test_id("login-password").fill("wrong-password")
    page.get_by_test_id("login-submit").click()
    wait_for(lambda: "Wrong username or password" in page.get_by_test_id("login-error").inner_text(), 10)

    page.get_by_test_id("login-password").fill("vera-password")
    page.get_by_test_id("login-submit").click()
    page.wait_for_url("**/history")
    wait_for(lambda: page.get_by_test_id("user-name").inner_text() == "vera · viewer", 10, what="user chip")
    # the session cookie is HttpOnly: page scripts cannot read it
    assert "fleet_session" not in page.evaluate("document.cookie")
    cookie = next(c for c in page.context.cookies() if c["name"] == "fleet_session")
    assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
    # a viewer may press the e-stop but not release it
    page.get_by_test_id("estop").click()
    wait_for(lambda: page.get_by_test_id("estop-release").is_visible(), 10, what="e-stop engaged")
    assert page.get_by_test_id("estop-release").is_disabled()
    with server.client() as admin:
        assert admin.get("/api/estop").json()["engaged"] is True
        admin.post("/api/estop/release", json={})

    page.get_by_test_id("logout").click()
    page.wait_for_url("**/login?next=*")
    page.goto("/")  # the old cookie is dead on the server: back to the login page
    page.wait_for_url("**/login?next=*")
    assert {f.split()[0] for f in rec.failures} <= {"401"}, rec.failures
    assert all(urlsplit(u).hostname == "127.0.0.1" for u in rec.requests)
