"""Password checks (scrypt: CPU and 16 MiB each) run on the server's password pool (issue 28): a user created,
a login, a wrong password and a password change are one job each there, and none ties up the event loop or the
threads that serve database reads. Real broker and server."""

from __future__ import annotations

from typing import Any

import httpx

from tests.support.procs import ServerProcess


def _passwords(c: httpx.Client) -> dict[str, Any]:
    stats: dict[str, Any] = c.get("/api/stats").json()["pools"]["passwords"]
    return stats


def test_every_password_check_runs_on_the_password_pool(server: ServerProcess) -> None:
    with server.client() as admin:
        before = _passwords(admin)["done"]
        assert admin.get("/api/users").status_code == 200  # no password in it: nothing on the pool
        assert _passwords(admin)["done"] == before
        body = {"username": "dora", "password": "dora-password-1", "role": "viewer"}
        assert admin.post("/api/users", json=body).status_code == 201
        assert _passwords(admin)["done"] == before + 1
        with server.client(anonymous=True) as c:
            good = c.post("/api/auth/login", json={"username": "dora", "password": "dora-password-1"})
            assert good.status_code == 200 and good.json()["username"] == "dora", good.text
            bad = c.post("/api/auth/login", json={"username": "dora", "password": "not-her-password"})
            assert (bad.status_code, bad.json()["code"]) == (401, "bad_credentials"), bad.text
            nobody = c.post("/api/auth/login", json={"username": "nobody", "password": "whatever-1"})
            assert nobody.status_code == 401  # checked all the same (a dummy hash): as slow as a wrong password
        assert _passwords(admin)["done"] == before + 4
        changed = admin.patch("/api/users/dora", json={"password": "dora-password-2"})
        assert changed.status_code == 200, changed.text
        assert _passwords(admin)["done"] == before + 5
        with server.client(anonymous=True) as c:
            again = c.post("/api/auth/login", json={"username": "dora", "password": "dora-password-2"})
            assert again.status_code == 200, again.text
        stats = _passwords(admin)
        assert stats["done"] == before + 6 and stats["refused"] == 0 and stats["busy_s"] > 0
