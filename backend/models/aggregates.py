"""Rollup tables (migration 0002): per-second and per-minute aggregates of raw telemetry, and the dirty
minutes still to roll up. See ``backend/store/rollup.py``.

One aggregate row per (robot_id, stream, bucket_ts) and resolution. Sums are stored rather than means so
buckets merge exactly: mean = sum / count. ``sealed``: retention deleted the raw rows under the bucket.
"""

from __future__ import annotations

from sqlalchemy import BigInteger, Boolean, Column, Double, PrimaryKeyConstraint, String, Table, Text, false

from backend.models.base import Base

#: resolution name -> bucket width in seconds
RESOLUTIONS: dict[str, float] = {"1s": 1.0, "1m": 60.0}


def _agg_table(name: str) -> Table:
    return Table(
        name,
        Base.metadata,
        Column("robot_id", String(64), nullable=False),
        Column("stream", String(64), nullable=False),
        Column("bucket_ts", Double, nullable=False),
        Column("n", BigInteger, nullable=False),
        Column("ts_sum", Double, nullable=False),
        Column("first_ts", Double, nullable=False),
        Column("last_ts", Double, nullable=False),
        Column("first_seq", BigInteger, nullable=False),
        Column("last_seq", BigInteger, nullable=False),
        *[Column(f"{axis}_{agg}", Double, nullable=True) for axis in ("x", "y", "z") for agg in ("sum", "min", "max")],
        Column("xyz_n", BigInteger, nullable=False, server_default="0"),
        Column("yaw", Double, nullable=True),
        Column("payload", Text, nullable=False),
        Column("sealed", Boolean, nullable=False, server_default=false()),
        PrimaryKeyConstraint("robot_id", "stream", "bucket_ts", name=f"pk_{name}"),
    )


TELEMETRY_1S = _agg_table("telemetry_1s")
TELEMETRY_1M = _agg_table("telemetry_1m")
AGG_TABLES: dict[str, Table] = {"1s": TELEMETRY_1S, "1m": TELEMETRY_1M}

TELEMETRY_DIRTY = Table(
    "telemetry_dirty",
    Base.metadata,
    Column("robot_id", String(64), nullable=False),
    Column("stream", String(64), nullable=False),
    Column("minute_ts", Double, nullable=False),
    Column("version", BigInteger, nullable=False, server_default="0"),
    PrimaryKeyConstraint("robot_id", "stream", "minute_ts", name="pk_telemetry_dirty"),
)
