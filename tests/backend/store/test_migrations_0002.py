"""Migration 0002 (aggregate tables, acks stored once): from an empty database, and from 0001 with data."""

from __future__ import annotations

import pytest
from alembic import command
from sqlalchemy import create_engine, inspect, text
from sqlalchemy.exc import IntegrityError

from backend.store.db import alembic_config, current_revision, upgrade_to, upgrade_to_head


def _engine(database_url: str):  # type: ignore[no-untyped-def]
    from backend.core.config import Settings
    from backend.store.db import create_db_engine

    return create_db_engine(Settings(database_url=database_url))


def test_upgrade_from_empty_to_0002_and_back(empty_database_url):
    engine = _engine(empty_database_url)
    try:
        upgrade_to(engine, "0002")
        assert current_revision(engine) == "0002"
        insp = inspect(engine)
        for table in ("telemetry_1s", "telemetry_1m"):
            cols = {c["name"] for c in insp.get_columns(table)}
            assert {
                "robot_id",
                "stream",
                "bucket_ts",
                "n",
                "ts_sum",
                "first_ts",
                "last_ts",
                "first_seq",
                "last_seq",
                "x_sum",
                "x_min",
                "x_max",
                "xyz_n",
                "yaw",
                "payload",
            } <= cols
            assert insp.get_pk_constraint(table)["constrained_columns"] == ["robot_id", "stream", "bucket_ts"]
        assert any(
            i["unique"] and i["column_names"] == ["command_id", "status", "ts"]
            for i in insp.get_indexes("command_acks")
        )
        assert insp.get_pk_constraint("telemetry_dirty")["constrained_columns"] == ["robot_id", "stream", "minute_ts"]
        cfg = alembic_config()
        with engine.begin() as conn:
            cfg.attributes["connection"] = conn
            command.downgrade(cfg, "0001")
        assert current_revision(engine) == "0001"
        assert "telemetry_1s" not in inspect(engine).get_table_names()
    finally:
        engine.dispose()


def test_upgrade_from_0001_with_data(empty_database_url):
    engine = _engine(empty_database_url)
    try:
        upgrade_to(engine, "0001")
        with engine.begin() as conn:
            conn.execute(
                text(
                    "INSERT INTO robots (id, legacy, agent_version, capabilities, first_seen, last_seen, online) "
                    "VALUES ('r1', false, 'v1', '{}', 1.0, 2.0, false)"
                )
            )
            conn.execute(
                text(
                    "INSERT INTO telemetry (robot_id, stream, ts, seq, x, y, z, yaw, payload) "
                    "VALUES ('r1', 'position', :ts, :seq, :x, 2.0, 0.0, 0.1, :p)"
                ),
                [
                    {"ts": 10.5, "seq": 0, "x": 1.0, "p": '{"x": 1.0}'},
                    {"ts": 10.6, "seq": 1, "x": 1.5, "p": '{"x": 1.5}'},
                ],
            )
            conn.execute(
                text(
                    "INSERT INTO commands (id, robot_id, command, args, source, ts, ttl_s, status, reason, updated_at) "
                    "VALUES ('c1', 'r1', 'stop', '{}', 'rest', 11.0, 2.0, 'done', '', 12.0)"
                )
            )
            # the same ack recorded twice (two replicas before 0002), plus a distinct one
            conn.execute(
                text(
                    "INSERT INTO command_acks (command_id, status, reason, ts, received_ts) VALUES "
                    "('c1', 'accepted', '', 11.1, 11.2), ('c1', 'accepted', '', 11.1, 11.3), "
                    "('c1', 'done', '', 11.5, 11.6)"
                )
            )
        upgrade_to_head(engine)
        with engine.connect() as conn:
            assert conn.execute(text("SELECT count(*) FROM telemetry")).scalar_one() == 2
            assert conn.execute(text("SELECT id, agent_version FROM robots")).one() == ("r1", "v1")
            acks = conn.execute(text("SELECT status, received_ts FROM command_acks ORDER BY ts")).all()
            assert [tuple(a) for a in acks] == [("accepted", 11.2), ("done", 11.6)]
            assert conn.execute(text("SELECT count(*) FROM telemetry_1s")).scalar_one() == 0
            # the stored minute is marked for the rollup job, which builds its aggregates
            marks = conn.execute(text("SELECT robot_id, stream, minute_ts FROM telemetry_dirty"))
            assert [tuple(r) for r in marks] == [("r1", "position", 0.0)]
        from backend.store.rollup import run_rollup

        assert run_rollup(engine, 1e9).minutes_rolled == 1
        with engine.connect() as conn:
            assert tuple(conn.execute(text("SELECT n, x_min, x_max FROM telemetry_1m")).one()) == (2, 1.0, 1.5)
        with pytest.raises(IntegrityError), engine.begin() as conn:
            conn.execute(
                text(
                    "INSERT INTO command_acks (command_id, status, reason, ts, received_ts) "
                    "VALUES ('c1', 'done', '', 11.5, 99.0)"
                )
            )
    finally:
        engine.dispose()


def test_cli_upgrade_reaches_head(empty_database_url):
    import subprocess

    from alembic.script import ScriptDirectory

    from tests.support.procs import VENV_BIN, base_env

    head = ScriptDirectory.from_config(alembic_config()).get_current_head()
    out = subprocess.run(
        [str(VENV_BIN / "fleet-server"), "db", "upgrade"],
        env=base_env(FLEET_DATABASE_URL=empty_database_url),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == head
    engine = create_engine(empty_database_url)
    try:
        assert {"telemetry_1s", "telemetry_1m"} <= set(inspect(engine).get_table_names())
    finally:
        engine.dispose()
