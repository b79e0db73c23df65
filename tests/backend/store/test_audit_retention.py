"""Audit retention: the trail is kept FLEET_RETENTION_AUDIT_DAYS (a year by default) and pruned by the same
retention pass as telemetry, which never deletes audit entries by its own (shorter) periods."""

from __future__ import annotations

import time

from sqlalchemy import Engine, insert, select, text

from backend.core.config import Settings
from backend.models import AuditRow
from backend.services.telemetry.ingest import telemetry_row
from backend.services.telemetry.rollups import RollupWorker
from backend.store.retention import run_retention
from backend.store.telemetry_inserts import dirty_marks, minutes_of, telemetry_insert

DAY = 86400.0


def _audit(engine: Engine, ages_days: list[float], now: float) -> None:
    with engine.begin() as conn:
        for i, age in enumerate(ages_days):
            conn.execute(
                insert(AuditRow).values(
                    ts=now - age * DAY,
                    actor="user:alice",
                    actor_name="alice",
                    token_id=None,
                    client="127.0.0.1",
                    action="estop",
                    robot_id=None,
                    detail={"n": i, "age_days": age},
                )
            )


def _ages(engine: Engine, now: float) -> list[float]:
    with engine.connect() as conn:
        return sorted(round((now - ts) / DAY) for (ts,) in conn.execute(select(AuditRow.ts)))


def _old_telemetry(engine: Engine, now: float) -> None:
    rows = [
        telemetry_row("r1", "battery", now - 40 * DAY + i, i, {"volts": 12.0}, now - 40 * DAY + i) for i in range(50)
    ]
    with engine.begin() as conn:
        conn.execute(telemetry_insert(engine), rows)
        conn.execute(dirty_marks(engine), minutes_of(rows))


def test_audit_kept_for_its_period_and_pruned_after(engine):
    now = time.time()
    _audit(engine, [500, 400, 366, 366, 366, 364, 200, 31, 1], now)
    report = run_retention(engine, now, raw_days=0, agg_days=0, chunk_rows=2, audit_days=365)
    assert report.audit_rows_deleted == 5  # in chunks of 2: 2 + 2 + 1
    assert _ages(engine, now) == [1, 31, 200, 364]


def test_telemetry_retention_never_deletes_audit(engine):
    now = time.time()
    _audit(engine, [400, 40, 2], now)
    _old_telemetry(engine, now)
    # telemetry goes after a day (raw and aggregates); the audit trail is kept forever (audit_days 0)
    report = run_retention(engine, now, raw_days=1, agg_days=1, audit_days=0)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM telemetry")).scalar_one() == 0
    assert report.raw_rows_deleted == 50 and report.agg_rows_deleted > 0  # the pass did delete, just not audit
    assert report.audit_rows_deleted == 0
    assert _ages(engine, now) == [2, 40, 400]


def test_worker_prunes_audit_with_the_setting(engine):
    settings = Settings()
    assert settings.retention_audit_days == 365.0  # a year by default, apart from telemetry's periods
    now = time.time()
    _audit(engine, [400, 366, 100], now)
    worker = RollupWorker(
        engine,
        raw_days=settings.retention_raw_days,
        agg_days=0,
        interval_s=3600,
        audit_days=settings.retention_audit_days,
    )
    worker.run_once(now)
    assert _ages(engine, now) == [100]
    assert worker.stats()["audit_rows_deleted"] == 2
