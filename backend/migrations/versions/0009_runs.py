"""Experiment runs and their markers (issue 19).

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-25
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0009"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BigId = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def upgrade() -> None:
    op.create_table(
        "runs",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("name", sa.String(200), nullable=False),
        sa.Column("notes", sa.Text(), nullable=False, server_default=""),
        sa.Column("tags", sa.JSON(), nullable=False),
        sa.Column("tag_index", sa.Text(), nullable=False, server_default="|"),
        sa.Column("operator", sa.String(160), nullable=False),
        sa.Column("robots", sa.JSON(), nullable=False),
        sa.Column("robot_index", sa.Text(), nullable=False, server_default="|"),
        sa.Column("started_at", sa.Double(), nullable=False),
        sa.Column("ended_at", sa.Double(), nullable=True),
        sa.Column("site_version", sa.BigInteger(), nullable=False, server_default="0"),
        sa.Column("agents", sa.JSON(), nullable=False),
        sa.Column("frame_rate", sa.Double(), nullable=False, server_default="5"),
        sa.Column("frames", sa.BigInteger(), nullable=False, server_default="0"),
        sa.Column("frame_bytes", sa.BigInteger(), nullable=False, server_default="0"),
        sa.Column("frames_stopped", sa.Boolean(), nullable=False, server_default=sa.false()),
        sa.Column("frames_stopped_reason", sa.Text(), nullable=False, server_default=""),
    )
    op.create_index("ix_runs_started_at", "runs", ["started_at"])
    op.create_table(
        "run_markers",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("run_id", sa.BigInteger(), nullable=False),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("text", sa.Text(), nullable=False),
        sa.Column("robot_id", sa.String(64), nullable=True),
        sa.Column("author", sa.String(160), nullable=False, server_default=""),
        sa.Column("created_at", sa.Double(), nullable=False),
    )
    op.create_index("ix_run_markers_run_ts", "run_markers", ["run_id", "ts"])


def downgrade() -> None:
    op.drop_index("ix_run_markers_run_ts", table_name="run_markers")
    op.drop_table("run_markers")
    op.drop_index("ix_runs_started_at", table_name="runs")
    op.drop_table("runs")
