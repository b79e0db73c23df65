"""History reads from the index alone (issue 28, the soak): the (robot_id, stream, ts) index becomes
(robot_id, stream, ts, x, y, z), so a bucketed GROUP BY over a robot's positions never visits the table.

Measured on the soak's database: the ten series of the history page took 0.22 s of CPU through the old
index (each row fetched from table pages shared with every robot and stream), 0.09 s through this one.
The old index is a prefix of the new one, so it is dropped: ingest keeps one index on (robot, stream, ts).

Revision ID: 0015
Revises: 0014
Create Date: 2026-11-29
"""

from collections.abc import Sequence

from alembic import op

revision: str = "0015"
down_revision: str | None = "0014"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_index("ix_telemetry_robot_stream_ts_xyz", "telemetry", ["robot_id", "stream", "ts", "x", "y", "z"])
    op.drop_index("ix_telemetry_robot_stream_ts", table_name="telemetry")


def downgrade() -> None:
    op.create_index("ix_telemetry_robot_stream_ts", "telemetry", ["robot_id", "stream", "ts"])
    op.drop_index("ix_telemetry_robot_stream_ts_xyz", table_name="telemetry")
