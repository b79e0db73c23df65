"""What the separation figures read (backend/store/separation.py) from a real database: a robot with more
positions than its share is thinned in the database to every k-th row (and interpolated across k times the
gap), stamps move onto the server's clock by the robot's measured offset, and the avoidance messages read
stop at their cap, saying so."""

from __future__ import annotations

import pytest
from sqlalchemy import Engine

from backend.services.runs.separation import MAX_GAP_S, from_samples
from backend.services.telemetry.ingest import telemetry_row
from backend.store.separation import read_samples
from backend.store.telemetry_inserts import telemetry_insert

T0 = 1_800_000_000.0


def _store(engine: Engine, rows: list[dict]) -> None:
    with engine.begin() as conn:
        conn.execute(telemetry_insert(engine), rows)


def test_reads_are_thinned_shifted_and_capped(engine: Engine) -> None:
    rows = [telemetry_row("a", "position", T0 + i * 0.05, i, {"x": i * 0.05, "y": 0.0}) for i in range(1000)]
    rows += [telemetry_row("b", "position", T0 + i * 0.1, i, {"x": 0.0, "y": 1.0}) for i in range(100)]
    # b's clock runs 2 s behind the server's: its health says so just before the stretch
    rows.append(telemetry_row("b", "health", T0 - 5, 0, {"clock_offset_ms": 2000.0}))
    rows += [
        telemetry_row("a", "avoidance", T0 + i, i, {"event": "active", "distance_m": 0.5 - i / 100, "duration_s": 0})
        for i in range(8)
    ]
    rows.append(telemetry_row("a", "position", T0 + 100, 1000, {"x": None, "y": None}))  # no fix: left out
    _store(engine, rows)

    got = read_samples(engine, ["a", "b"], T0, T0 + 60, 300, 5, "avoidance")
    a, b = got["a"], got["b"]
    assert a.step == 4 and a.t.size == 250  # every 4th of 1000
    assert a.t[:3].tolist() == [T0, T0 + 0.2, T0 + 0.4] and a.x[1] == 0.2
    assert b.step == 1 and b.t.size == 100 and b.t[0] == T0 + 2.0  # on the server's clock
    assert len(a.avoidance) == 5 and a.avoidance_truncated and not b.avoidance_truncated

    stats = from_samples(got, 0.3, T0)
    assert stats.step == {"a": 4, "b": 1} and stats.samples == {"a": 250, "b": 100}
    assert stats.interventions_by_robot["a"].truncated and stats.interventions_by_robot["a"].count == 1
    assert stats.interventions_by_robot["a"].min_distance_m == 0.46
    # b (shifted) and a overlap from T0 + 2 on: a is at x = 2.0 there, b at x = 0, y = 1
    assert stats.closest is not None and stats.closest.distance_m == pytest.approx(5**0.5, abs=1e-4)
    assert stats.closest.ts == pytest.approx(T0 + 2.0)
    # b's 100 samples, a's 50 kept ones within b's stretch (interpolated across 4 s: it was thinned 4-fold)
    assert stats.pairs[0].samples == 100 + 50 and MAX_GAP_S * a.step == 4.0
