"""Logging in through the login page in a real Chromium: redirect to /login, wrong password, the HttpOnly
session cookie, back to the page asked for, the role in the top bar, logout ending the session."""

from __future__ import annotations

from urllib.parse import urlencode, urlsplit

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


# ?next= as an attacker writes it -> where the login page may send the browser (always a path of this site)
NEXT_VARIANTS = {
    "/history": "/history",
    "/history?x=1#y": "/history?x=1#y",
    "/%09/evil.example": "/",  # a tab: URL parsers drop it, "//evil.example" is another site
    "/\t/evil.example": "/",
    "/\n/evil.example": "/",
    "//evil.example": "/",
    "/\\evil.example": "/",
    "\\/evil.example": "/",
    "https://evil.example/": "/",
    "javascript:alert(1)": "/",
    "/login?next=//evil.example": "/",
}


def test_next_only_ever_leads_to_this_site(server, page_factory):
    page, rec = page_factory()  # logged in: the login page goes on to ?next= at once
    for raw, expected in NEXT_VARIANTS.items():
        query = raw if raw.startswith("/%09") else None
        page.goto(f"/login?next={query}" if query else "/login?" + urlencode({"next": raw}))
        page.wait_for_url(lambda u: urlsplit(u).path != "/login")
        got = urlsplit(page.url)
        assert got.hostname == "127.0.0.1" and got.port == server.port, (raw, page.url)
        assert got.path + (f"?{got.query}" if got.query else "") + (f"#{got.fragment}" if got.fragment else "") == (
            expected
        ), (raw, page.url)
    assert rec.console_errors == [], rec.console_errors  # and no Content-Security-Policy violation
