"""One operator in control, in two real browser contexts: "driven by" shows in the second, a request reaches
the first, which grants it; the e-stop works for both throughout."""

from __future__ import annotations

from typing import Any

import pytest

from tests.support.procs import ServerProcess


def _login_state(server: ServerProcess, username: str, role: str) -> dict[str, Any]:
    password = f"{username}-password-1"
    with server.client() as c:
        r = c.post("/api/users", json={"username": username, "password": password, "role": role})
        assert r.status_code in (201, 409), r.text
    with server.client(anonymous=True) as c:
        r = c.post("/api/auth/login", json={"username": username, "password": password})
        assert r.status_code == 200, r.text
        value = r.cookies["fleet_session"]
    cookie = {
        "name": "fleet_session",
        "value": value,
        "domain": "127.0.0.1",
        "path": "/",
        "expires": -1,
        "httpOnly": True,
        "secure": False,
        "sameSite": "Strict",
    }
    return {"storage_state": {"cookies": [cookie], "origins": []}}


def _robot_page(browser: Any, server: ServerProcess, username: str, rid: str) -> Any:
    ctx = browser.new_context(
        viewport={"width": 1280, "height": 720}, base_url=server.base_url, **_login_state(server, username, "operator")
    )
    page = ctx.new_page()
    page.goto(f"/robots/{rid}")
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    page.get_by_test_id("control-state").wait_for()
    return page


@pytest.mark.slow
def test_driven_by_request_and_grant_between_two_operators(server, fleet, browser):
    alice = _robot_page(browser, server, "alice", "snail-1")
    bob = _robot_page(browser, server, "bob", "snail-1")
    try:
        assert "Nobody drives it" in bob.get_by_test_id("control-state").inner_text()
        # alice drives with the pad: the lease is hers, and bob's page says so within moments
        forward = alice.locator("[data-testid=drive-forward]:visible")
        forward.hover()
        alice.mouse.down()
        bob.wait_for_function(
            "() => document.querySelector('[data-testid=control-state]').textContent.includes('Driven by alice')"
        )
        alice.mouse.up()
        assert "You have control" in alice.get_by_test_id("control-state").inner_text()
        bob.wait_for_function(
            "() => [...document.querySelectorAll('[data-testid=drive-forward]')].every(b => b.disabled)"
        )
        assert "Driven by alice" in bob.locator("[data-testid=drive-reason]:visible").inner_text()

        # bob asks; alice sees the request and grants it; now bob may drive and alice may not
        bob.get_by_test_id("request-control").click()
        alice.get_by_test_id("lease-request").wait_for()
        assert "bob asks for control of snail-1" in alice.get_by_test_id("lease-request").inner_text()
        alice.get_by_test_id("grant-control").click()
        bob.wait_for_function(
            "() => document.querySelector('[data-testid=control-state]').textContent.includes('You have control')"
        )
        alice.wait_for_function(
            "() => document.querySelector('[data-testid=control-state]').textContent.includes('Driven by bob')"
        )
        bob.wait_for_function(
            "() => [...document.querySelectorAll('[data-testid=drive-forward]')].some(b => !b.disabled)"
        )

        # the e-stop is never subject to the lease: alice, who no longer drives, presses it
        alice.get_by_test_id("estop").click()
        bob.wait_for_function("() => window.fleetDebug.estop().engaged")
        with server.client() as c:
            assert c.get("/api/estop").json()["engaged"] is True
            assert c.post("/api/estop/release", json={}).status_code == 202
    finally:
        alice.context.close()
        bob.context.close()
