"""A run's Parquet export stays bounded whatever keys a robot sends: a typed column for the first
``max_fields`` distinct keys of a stream, the rest of each row's keys as one JSON object in
``other_fields``; every value is still there."""

from __future__ import annotations

import io
import time
from collections.abc import Iterator

import orjson
import pyarrow.parquet as pq
import pytest
from sqlalchemy import Engine

from backend.core.config import Settings
from backend.services.runs.export import OTHER_FIELDS, write_parquet
from backend.store.db import create_db_engine
from backend.store.telemetry_inserts import telemetry_insert


@pytest.fixture
def engine(database_url: str) -> Iterator[Engine]:
    eng = create_db_engine(Settings(database_url=database_url))
    try:
        yield eng
    finally:
        eng.dispose()


def test_a_robot_sending_new_keys_in_every_message_gets_capped_columns(engine: Engine) -> None:
    t0 = time.time() - 60
    # x and n in every message, and 20 keys never seen before in each: 1,002 distinct keys in 50 rows
    sent = [{"x": i * 0.5, "n": i, **{f"k{i}_{j}": j for j in range(20)}} for i in range(50)]
    values = [
        {
            "robot_id": "wild",
            "stream": "odd",
            "seq": i,
            "ts": t0 + i * 0.1,
            "x": None,
            "y": None,
            "z": None,
            "yaw": None,
            "payload": orjson.dumps(data).decode(),
            "recv_ts": t0 + i * 0.1,
        }
        for i, data in enumerate(sent)
    ]
    with engine.begin() as conn:
        conn.execute(telemetry_insert(engine), values)

    out = io.BytesIO()
    assert write_parquet(engine, ["wild"], t0 - 1, t0 + 10, "odd", out, max_fields=10) == 50
    table = pq.read_table(io.BytesIO(out.getvalue()))
    columns = table.column_names
    # robot_id, ts, recv_ts, seq, the first 10 keys seen (x, n and 8 of the first row's), and the rest in one
    assert columns[:6] == ["robot_id", "ts", "recv_ts", "seq", "x", "n"] and len(columns) == 4 + 10 + 1
    assert columns[-1] == OTHER_FIELDS and str(table.schema.field("x").type) == "double"
    assert b"fleet.other_fields" in (table.schema.metadata or {})
    for data, row in zip(sent, table.to_pylist(), strict=True):
        own = {k: v for k, v in row.items() if k not in ("robot_id", "ts", "recv_ts", "seq", OTHER_FIELDS)}
        rebuilt = {k: v for k, v in own.items() if v is not None} | orjson.loads(row[OTHER_FIELDS] or "{}")
        assert rebuilt == data  # nothing lost
