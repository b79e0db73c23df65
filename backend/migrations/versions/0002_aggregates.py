"""Telemetry rollups (per second, per minute) for fast long-range queries and retention; acks stored once.

Revision ID: 0002
Revises: 0001
Create Date: 2025-01-02

* ``telemetry_1s`` / ``telemetry_1m``: per (robot, stream, bucket) count, sums (mean = sum / count, so
  buckets merge exactly), min/max, first/last seq and time, the last row's yaw and payload. Kept up to
  date from the raw rows by the rollup job; ``sealed`` once retention has deleted the raw rows under it.
* ``telemetry_dirty``: the minutes (per robot and stream) whose raw rows changed since their last rollup;
  the writer marks them in the same transaction as the rows (``version`` counts the marks). Every minute
  already stored is marked here, so the rollup job builds the aggregates of existing data too.
* ``command_acks``: an ack seen by several replicas (each subscribes to acks) is stored once: unique
  (command_id, status, ts). Duplicates already stored are removed first.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

AGG_TABLES = ("telemetry_1s", "telemetry_1m")


def _agg_table(name: str) -> None:
    op.create_table(
        name,
        sa.Column("robot_id", sa.String(64), nullable=False),
        sa.Column("stream", sa.String(64), nullable=False),
        sa.Column("bucket_ts", sa.Double(), nullable=False),
        sa.Column("n", sa.BigInteger(), nullable=False),
        sa.Column("ts_sum", sa.Double(), nullable=False),
        sa.Column("first_ts", sa.Double(), nullable=False),
        sa.Column("last_ts", sa.Double(), nullable=False),
        sa.Column("first_seq", sa.BigInteger(), nullable=False),
        sa.Column("last_seq", sa.BigInteger(), nullable=False),
        *[
            sa.Column(f"{axis}_{agg}", sa.Double(), nullable=True)
            for axis in ("x", "y", "z")
            for agg in ("sum", "min", "max")
        ],
        sa.Column("xyz_n", sa.BigInteger(), nullable=False, server_default="0"),
        sa.Column("yaw", sa.Double(), nullable=True),
        sa.Column("payload", sa.Text(), nullable=False),
        sa.Column("sealed", sa.Boolean(), nullable=False, server_default=sa.false()),
        sa.PrimaryKeyConstraint("robot_id", "stream", "bucket_ts", name=f"pk_{name}"),
    )


def upgrade() -> None:
    for name in AGG_TABLES:
        _agg_table(name)
    op.create_table(
        "telemetry_dirty",
        sa.Column("robot_id", sa.String(64), nullable=False),
        sa.Column("stream", sa.String(64), nullable=False),
        sa.Column("minute_ts", sa.Double(), nullable=False),
        sa.Column("version", sa.BigInteger(), nullable=False, server_default="0"),
        sa.PrimaryKeyConstraint("robot_id", "stream", "minute_ts", name="pk_telemetry_dirty"),
    )
    minute = (
        "floor(ts / 60.0) * 60.0" if op.get_bind().dialect.name == "postgresql" else "CAST(ts / 60 AS INTEGER) * 60.0"
    )
    op.execute(
        f"INSERT INTO telemetry_dirty (robot_id, stream, minute_ts, version) "
        f"SELECT DISTINCT robot_id, stream, {minute}, 0 FROM telemetry"
    )
    # Keep the first of identical acks, then make them unique.
    op.execute(
        "DELETE FROM command_acks WHERE id NOT IN ("
        " SELECT min_id FROM (SELECT min(id) AS min_id FROM command_acks GROUP BY command_id, status, ts) AS k)"
    )
    op.create_index("uq_command_acks_command_status_ts", "command_acks", ["command_id", "status", "ts"], unique=True)


def downgrade() -> None:
    op.drop_index("uq_command_acks_command_status_ts", table_name="command_acks")
    op.drop_table("telemetry_dirty")
    for name in reversed(AGG_TABLES):
        op.drop_table(name)
