"""The rollup worker: a thread that keeps the aggregates current, and runs the retention pass on its turn.

Every ``FLEET_ROLLUP_INTERVAL_S`` (5 s) the minutes whose raw rows changed are rolled up into the
per-second and per-minute tables (``backend/store/rollup.py``), so long-range history queries read
aggregates. Every ``FLEET_RETENTION_INTERVAL_S`` the retention pass (``backend/store/retention.py``)
deletes raw telemetry older than ``FLEET_RETENTION_RAW_DAYS`` (its aggregates stay, sealed) and prunes
aggregates older than ``FLEET_RETENTION_AGG_DAYS``, and audit entries older than
``FLEET_RETENTION_AUDIT_DAYS`` (a year; telemetry's settings never touch the audit trail). Both share one
thread so they never run at once.
The thread uses its own database connection and short transactions, so it never blocks the event loop
and only ever holds the (SQLite) write lock for one small chunk at a time. Replicas on PostgreSQL may all
run it: an advisory lock lets one at a time do the work.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Any

from sqlalchemy import Engine

from backend.store.retention import run_retention
from backend.store.rollup import RollupReport, run_rollup

log = logging.getLogger(__name__)

#: the first retention pass runs this long after start (or after interval_s when that is shorter)
FIRST_RUN_DELAY_S = 30.0


class RollupWorker:
    def __init__(
        self,
        engine: Engine,
        raw_days: float,
        agg_days: float,
        interval_s: float,
        chunk_rows: int = 20_000,
        rollup_interval_s: float = 5.0,
        audit_days: float = 0.0,
    ) -> None:
        self._engine = engine
        self.raw_days = raw_days
        self.agg_days = agg_days
        self.audit_days = audit_days
        self.interval_s = interval_s
        self.rollup_interval_s = rollup_interval_s
        self.chunk_rows = chunk_rows
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rollup-retention", daemon=True)
        self.runs = 0
        self.rollups = 0
        self.errors = 0
        self.last_run: float | None = None
        self.last_duration_s: float | None = None
        self.last_report: RollupReport | None = None
        self.minutes_rolled = 0
        self.raw_rows_deleted = 0
        self.audit_rows_deleted = 0

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def rollup_once(self, now: float | None = None, settle_s: float = 2.0, budget_s: float = 5.0) -> RollupReport:
        """Roll up what changed, for at most about ``budget_s`` seconds (a backlog takes several passes)."""
        report = run_rollup(self._engine, time.time() if now is None else now, settle_s, budget_s=budget_s)
        self.rollups += 1
        self.minutes_rolled += report.minutes_rolled
        return report

    def run_once(self, now: float | None = None) -> RollupReport:
        """One retention pass (it rolls up what is old enough first)."""
        t0 = time.monotonic()
        report = run_retention(
            self._engine,
            time.time() if now is None else now,
            self.raw_days,
            self.agg_days,
            self.chunk_rows,
            audit_days=self.audit_days,
        )
        self.runs += 1
        self.last_run = time.time()
        self.last_duration_s = round(time.monotonic() - t0, 3)
        self.last_report = report
        self.minutes_rolled += report.minutes_rolled
        self.raw_rows_deleted += report.raw_rows_deleted
        self.audit_rows_deleted += report.audit_rows_deleted
        if report.raw_rows_deleted or report.agg_rows_deleted or report.late_rows_merged or report.audit_rows_deleted:
            log.info(
                "retention: %d raw rows deleted under sealed aggregates, %d late rows merged, "
                "%d aggregate rows pruned, %d audit entries pruned in %.2f s",
                report.raw_rows_deleted,
                report.late_rows_merged,
                report.agg_rows_deleted,
                report.audit_rows_deleted,
                self.last_duration_s,
            )
        return report

    def stats(self) -> dict[str, Any]:
        last = self.last_report
        return {
            "raw_days": self.raw_days,
            "agg_days": self.agg_days,
            "audit_days": self.audit_days,
            "interval_s": self.interval_s,
            "rollup_interval_s": self.rollup_interval_s,
            "runs": self.runs,
            "rollups": self.rollups,
            "errors": self.errors,
            "last_run": self.last_run,
            "last_duration_s": self.last_duration_s,
            "last_raw_rows_deleted": last.raw_rows_deleted if last else 0,
            "last_skipped_locked": last.skipped_locked if last else False,
            "minutes_rolled": self.minutes_rolled,
            "raw_rows_deleted": self.raw_rows_deleted,
            "audit_rows_deleted": self.audit_rows_deleted,
        }

    def _run(self) -> None:
        enabled = self.raw_days > 0 or self.agg_days > 0 or self.audit_days > 0
        next_retention = time.monotonic() + min(FIRST_RUN_DELAY_S, self.interval_s) if enabled else math.inf
        while not self._stop.wait(max(0.0, min(self.rollup_interval_s, next_retention - time.monotonic()))):
            try:
                self.rollup_once()
                if time.monotonic() >= next_retention:
                    next_retention = time.monotonic() + self.interval_s
                    self.run_once()
            except Exception:
                self.errors += 1
                log.exception("rollup/retention pass failed (retried on the next pass)")
