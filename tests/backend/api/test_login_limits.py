"""Logins against a real server: limited per address and for everyone before any password is checked (so a
flood of user names never reaches scrypt), and every checked attempt logged and in the audit trail."""

from __future__ import annotations

from typing import Any

import httpx

from tests.support.procs import ServerProcess, wait_for


def _login_from(server: ServerProcess, address: str, username: str, password: str) -> httpx.Response:
    """A login from the client address ``address`` (any 127.x address reaches the server on 127.0.0.1)."""
    transport = httpx.HTTPTransport(local_address=address)
    with httpx.Client(base_url=server.base_url, timeout=15, transport=transport) as c:
        return c.post("/api/auth/login", json={"username": username, "password": password})


def _password_checks(server: ServerProcess) -> int:
    with server.client() as admin:
        return int(admin.get("/api/stats").json()["pools"]["passwords"]["done"])


def _trail(server: ServerProcess, action: str) -> list[dict[str, Any]]:
    with server.client() as admin:
        r = admin.get("/api/audit", params={"action": action, "limit": 1000})
        assert r.status_code == 200, r.text
        return list(r.json())


def test_many_user_names_from_one_address_are_refused_before_scrypt(broker, database_url, workdir) -> None:
    server = ServerProcess(
        broker,
        database_url,
        workdir,
        FLEET_LOGIN_ADDRESS_BURST="3",
        FLEET_LOGIN_ADDRESS_RATE_PER_S="0.001",
        FLEET_LOGIN_TOTAL_BURST="6",
        FLEET_LOGIN_TOTAL_RATE_PER_S="0.001",
    )
    server.start()
    try:
        # a successful login is audited too (and takes one of everyone's 6)
        with server.client() as admin:
            r = admin.post("/api/users", json={"username": "ada", "password": "correct horse", "role": "viewer"})
            assert r.status_code == 201, r.text
        assert _login_from(server, "127.0.0.3", "ada", "correct horse").status_code == 200
        wait_for(lambda: len(_trail(server, "login")) == 1, 10, what="the login audited")
        (entry,) = _trail(server, "login")
        assert entry["actor"] == "user:ada" and entry["client"] == "127.0.0.3" and entry["token_id"].startswith("ses_")

        before = _password_checks(server)
        # a new user name every time: the per-(name, address) limit alone would let all of them through
        first = [_login_from(server, "127.0.0.1", f"nobody-{i}", "guess-guess") for i in range(6)]
        assert [r.status_code for r in first] == [401, 401, 401, 429, 429, 429], [r.text for r in first]
        assert all(int(r.headers["retry-after"]) >= 1 for r in first[3:])
        # another address has its own limit, but everyone together only 6 (ada's success was one)
        second = [_login_from(server, "127.0.0.2", f"other-{i}", "guess-guess") for i in range(4)]
        assert [r.status_code for r in second] == [401, 401, 429, 429], [r.text for r in second]
        assert _password_checks(server) - before == 5  # the refused ones never ran scrypt

        # every checked attempt is in the log and the audit trail (with the name tried and the address)
        wait_for(lambda: len(_trail(server, "login_failed")) == 5, 10, what="5 failed logins audited")
        failed = {(e["detail"]["username"], e["client"], e["actor"]) for e in _trail(server, "login_failed")}
        assert failed == {
            *((f"nobody-{i}", "127.0.0.1", "anonymous") for i in range(3)),
            *((f"other-{i}", "127.0.0.2", "anonymous") for i in range(2)),
        }
        out = server.output()
        assert "failed login for 'nobody-0' from 127.0.0.1 (bad_credentials)" in out
        assert "failed login for 'other-1' from 127.0.0.2" in out
        assert "login attempts from 127.0.0.1 refused: too many" in out
    finally:
        server.stop()
