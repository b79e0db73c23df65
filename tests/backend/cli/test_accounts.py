"""`fleet-server users add` and `create-admin` write only to the server's database (issue 21): they name
the database they used, and refuse the built-in default (FLEET_DATABASE_URL unset, relative to the current
directory) or a database without the server's schema, unless given --force. Real CLI processes against a
real server's database."""

from __future__ import annotations

import sqlite3
import subprocess
from pathlib import Path

import httpx
import pytest

from tests.support.procs import VENV_BIN, ServerProcess, base_env

PASSWORD = "first-admin-password"


def _cli(*args: str, cwd: Path, stdin: str = "", **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(VENV_BIN / "fleet-server"), *args],
        cwd=cwd,
        env=base_env(**env),
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
    )


def _login(server: ServerProcess, username: str, password: str) -> httpx.Response:
    with server.client(anonymous=True) as c:
        return c.post("/api/auth/login", json={"username": username, "password": password})


def _sqlite_path(server: ServerProcess) -> Path | None:
    url = server.database_url
    return Path(url.removeprefix("sqlite:///")) if url.startswith("sqlite:///") else None


def test_users_add_without_database_url_refuses_and_writes_nothing(server, tmp_path):
    out = _cli("users", "add", "ada", "--role", "admin", "--password-stdin", cwd=tmp_path, stdin=f"{PASSWORD}\n")
    assert out.returncode == 1, out.stdout
    assert "FLEET_DATABASE_URL is not set" in out.stderr and str(tmp_path / "data" / "fleet.db") in out.stderr
    assert "--force" in out.stderr
    assert not (tmp_path / "data").exists()  # no stray database was created
    assert _login(server, "ada", PASSWORD).status_code == 401
    # create-admin refuses the same way
    out = _cli("create-admin", cwd=tmp_path)
    assert out.returncode == 1 and "FLEET_DATABASE_URL is not set" in out.stderr and out.stdout == ""
    # told otherwise, it uses the default (and says where), creating the schema there
    out = _cli("users", "add", "ada", "--password-stdin", "--force", cwd=tmp_path, stdin=f"{PASSWORD}\n")
    assert out.returncode == 0, out.stderr
    assert f"written to SQLite file {tmp_path / 'data' / 'fleet.db'}" in out.stdout
    with sqlite3.connect(tmp_path / "data" / "fleet.db") as db:
        assert db.execute("SELECT username FROM users").fetchall() == [("ada",)]


def test_users_add_to_a_database_without_schema_refuses(server, tmp_path):
    typo = tmp_path / "flet.db"  # a typo in the path: not the server's database
    out = _cli(
        "users",
        "add",
        "ada",
        "--password-stdin",
        cwd=tmp_path,
        stdin=f"{PASSWORD}\n",
        FLEET_DATABASE_URL=f"sqlite:///{typo}",
    )
    assert out.returncode == 1 and f"SQLite file {typo} does not exist" in out.stderr, out.stderr
    assert not typo.exists()
    sqlite3.connect(typo).close()  # exists, but empty: no server ever ran with it
    out = _cli(
        "users",
        "add",
        "ada",
        "--password-stdin",
        cwd=tmp_path,
        stdin=f"{PASSWORD}\n",
        FLEET_DATABASE_URL=f"sqlite:///{typo}",
    )
    assert out.returncode == 1 and "holds no server schema" in out.stderr, out.stderr
    with sqlite3.connect(typo) as db:
        assert db.execute("SELECT name FROM sqlite_master").fetchall() == []


def test_users_add_to_the_servers_database_says_where_and_logs_in(server, tmp_path):
    out = _cli(
        "users",
        "add",
        "ada",
        "--role",
        "admin",
        "--password-stdin",
        cwd=tmp_path,
        stdin=f"{PASSWORD}\n",
        FLEET_DATABASE_URL=server.database_url,
    )
    assert out.returncode == 0, out.stderr
    path = _sqlite_path(server)
    where = f"SQLite file {path.resolve()}" if path else server.database_url.split("@")[-1]
    assert "user ada: role admin, written to" in out.stdout and where in out.stdout, out.stdout
    assert _login(server, "ada", PASSWORD).json()["role"] == "admin"
    listed = _cli("users", "list", cwd=tmp_path, FLEET_DATABASE_URL=server.database_url)
    assert "ada\tadmin" in listed.stdout and where in listed.stderr


@pytest.mark.parametrize("action", ["remove", "list"])
def test_every_users_action_checks_the_database(tmp_path, action):
    out = _cli("users", action, "ada", cwd=tmp_path)
    assert out.returncode == 1 and "FLEET_DATABASE_URL is not set" in out.stderr
    assert not (tmp_path / "data").exists()


def test_cli_account_changes_are_in_the_audit_trail(server, tmp_path):
    """What the CLI changes in the server's database is audited there too, by the OS account that ran it."""
    db = {"FLEET_DATABASE_URL": server.database_url}
    stdin = f"{PASSWORD}\n"
    assert _cli("users", "add", "cli-bea", "--password-stdin", cwd=tmp_path, stdin=stdin, **db).returncode == 0
    assert (
        _cli(
            "users", "add", "cli-bea", "--role", "operator", "--password-stdin", cwd=tmp_path, stdin=stdin, **db
        ).returncode
        == 0
    )
    assert _cli("users", "remove", "cli-bea", cwd=tmp_path, **db).returncode == 0
    made = _cli("create-admin", "--name", "cli-admin", cwd=tmp_path, **db)
    assert made.returncode == 0, made.stderr
    with server.client() as c:
        trail = list(reversed(c.get("/api/audit", params={"limit": 100}).json()))
    cli = [(e["action"], e["detail"]) for e in trail if e["client"] == "cli"]
    assert cli[:3] == [
        ("user_create", {"user": "cli-bea", "role": "viewer"}),
        ("user_update", {"user": "cli-bea", "role": "operator", "password_reset": True}),
        ("user_delete", {"user": "cli-bea"}),
    ]
    assert cli[3][0] == "token_create" and cli[3][1]["name"] == "cli-admin" and cli[3][1]["role"] == "admin"
    assert all(
        e["actor"].startswith("cli:") and "(fleet-server CLI)" in e["actor_name"] for e in trail if e["client"] == "cli"
    )
    assert len(cli) == 4 and PASSWORD not in str(trail) and made.stdout.strip() not in str(trail)
