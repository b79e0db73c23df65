"""Schema via Alembic: from an empty database to head with ``fleet-server db upgrade``."""

from __future__ import annotations

import subprocess

from sqlalchemy import create_engine, inspect

from tests.support.procs import VENV_BIN, base_env


def _head() -> str:
    from alembic.script import ScriptDirectory

    from backend.store.db import alembic_config

    head = ScriptDirectory.from_config(alembic_config()).get_current_head()
    assert head is not None
    return head


def _cli(database_url: str, *args: str) -> str:
    out = subprocess.run(
        [str(VENV_BIN / "fleet-server"), "db", *args],
        env=base_env(FLEET_DATABASE_URL=database_url),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_upgrade_from_empty_database(empty_database_url):
    assert _cli(empty_database_url, "current") == "(empty database)"
    head = _head()
    assert _cli(empty_database_url, "upgrade") == head
    assert _cli(empty_database_url, "upgrade") == head  # idempotent
    assert _cli(empty_database_url, "current") == head
    engine = create_engine(empty_database_url)
    try:
        insp = inspect(engine)
        assert {"robots", "telemetry", "commands", "command_acks", "events", "alembic_version"} <= set(
            insp.get_table_names()
        )
        cols = {c["name"] for c in insp.get_columns("telemetry")}
        assert {"robot_id", "stream", "ts", "seq", "x", "y", "z", "yaw", "payload"} <= cols
        uniques = [tuple(u["column_names"]) for u in insp.get_unique_constraints("telemetry")]
        assert ("robot_id", "stream", "seq", "ts") in uniques
        # covering (migration 0015): a history GROUP BY over positions reads the index alone
        indexes = [i["column_names"] for i in insp.get_indexes("telemetry")]
        assert ["robot_id", "stream", "ts", "x", "y", "z"] in indexes
        assert ["robot_id", "stream", "ts"] not in indexes
    finally:
        engine.dispose()


def test_production_refuses_placeholder_secrets(empty_database_url):
    out = subprocess.run(
        [str(VENV_BIN / "fleet-server"), "db", "current"],
        env=base_env(
            FLEET_DATABASE_URL=empty_database_url,
            FLEET_ENVIRONMENT="production",
            FLEET_SECRET_KEY="changeme",
            FLEET_ADMIN_TOKEN="x" * 32,
        ),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and "FLEET_SECRET_KEY" in out.stderr
    ok = subprocess.run(
        [str(VENV_BIN / "fleet-server"), "db", "current"],
        env=base_env(
            FLEET_DATABASE_URL=empty_database_url,
            FLEET_ENVIRONMENT="production",
            FLEET_SECRET_KEY="s" * 40,
            FLEET_ADMIN_TOKEN="t" * 40,
        ),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert ok.returncode == 0, ok.stderr


def test_downgrade_and_upgrade_again(empty_database_url):
    """The documented way back to an older release: `fleet-server db downgrade REV`, then up again."""
    head = _cli(empty_database_url, "upgrade")
    assert _cli(empty_database_url, "downgrade", "0002") == "0002"
    engine = create_engine(empty_database_url)
    try:
        tables = set(inspect(engine).get_table_names())
    finally:
        engine.dispose()
    assert "telemetry" in tables and "users" not in tables and "api_tokens" not in tables
    assert _cli(empty_database_url, "upgrade") == head
    out = subprocess.run(
        [str(VENV_BIN / "fleet-server"), "db", "downgrade"],
        env=base_env(FLEET_DATABASE_URL=empty_database_url),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and "revision" in out.stderr
