"""The audit trail of user and token changes (``GET /api/audit``), its filters and paging, against a real
server with authentication on. Secrets never reach the trail."""

from __future__ import annotations

import time
from typing import Any

from tests.support.procs import ServerProcess, wait_for

PASSWORD = "correct horse battery"
NEW_PASSWORD = "another long passphrase"


def _trail(c: Any, **params: Any) -> list[dict[str, Any]]:
    r = c.get("/api/audit", params={"limit": 1000, **params})
    assert r.status_code == 200, r.text
    return list(reversed(r.json()))  # oldest first


def test_user_and_token_changes_are_audited_and_filtered(server: ServerProcess) -> None:
    t0 = time.time()
    with server.client() as admin:
        assert (
            admin.post("/api/users", json={"username": "carol", "password": PASSWORD, "role": "viewer"}).status_code
            == 201
        )
        assert admin.patch("/api/users/carol", json={"role": "operator"}).status_code == 200
        assert admin.patch("/api/users/carol", json={"password": NEW_PASSWORD}).status_code == 200
        assert admin.patch("/api/users/carol", json={"disabled": True}).status_code == 200
        created = admin.post("/api/tokens", json={"name": "ci-script", "role": "operator"}).json()
        assert admin.delete(f"/api/tokens/{created['id']}").status_code == 204
        assert admin.delete("/api/users/carol").status_code == 204
        # refused changes are not audited as done
        assert admin.patch("/api/users/nobody", json={"role": "admin"}).status_code == 404
        assert admin.delete("/api/tokens/tok_nope").status_code == 404

        expected = [
            ("user_create", {"user": "carol", "role": "viewer"}),
            ("user_update", {"user": "carol", "role": "operator"}),
            ("user_update", {"user": "carol", "password_reset": True}),
            ("user_update", {"user": "carol", "disabled": True}),
            (
                "token_create",
                {"token": created["id"], "name": "ci-script", "role": "operator", "expires_at": created["expires_at"]},
            ),
            ("token_revoke", {"token": created["id"]}),
            ("user_delete", {"user": "carol"}),
        ]
        entries = wait_for(lambda: len(_trail(admin)) >= len(expected) and _trail(admin), 5, what="the trail")
        assert [(e["action"], e["detail"]) for e in entries] == expected
        assert all(e["actor_name"] == "FLEET_ADMIN_TOKEN" and e["client"] == "127.0.0.1" for e in entries)
        text = str(entries)
        assert PASSWORD not in text and NEW_PASSWORD not in text and created["token"] not in text

        # filters: action, actor (subject or name), time range; paging newest first with before_id
        assert [e["detail"] for e in _trail(admin, action="token_revoke")] == [{"token": created["id"]}]
        assert len(_trail(admin, actor="FLEET_ADMIN_TOKEN")) == len(expected)
        assert _trail(admin, actor="someone-else") == []
        assert _trail(admin, end=t0 - 1) == [] and len(_trail(admin, start=t0 - 1)) == len(expected)
        newest = admin.get("/api/audit", params={"limit": 3}).json()
        assert [e["action"] for e in newest] == ["user_delete", "token_revoke", "token_create"]
        older = admin.get("/api/audit", params={"limit": 3, "before_id": newest[-1]["id"]}).json()
        assert [e["action"] for e in older] == ["user_update", "user_update", "user_update"]
        assert admin.get("/api/audit", params={"limit": 0}).status_code == 422
        # found by schemathesis: an id past any database integer was a 500
        r = admin.get("/api/audit", params={"before_id": 2**70})
        assert r.status_code == 422 and r.json()["code"] == "validation_error", r.text

        # the trail is for admins only
        token = admin.post("/api/tokens", json={"name": "op", "role": "operator"}).json()["token"]
        with server.client(token) as op:
            r = op.get("/api/audit")
            assert r.status_code == 403 and r.json()["code"] == "forbidden"
