"""Missions, their state transitions and their events.

Revision ID: 0010
Revises: 0009
Create Date: 2026-11-25
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0010"
down_revision: str | None = "0009"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BigId = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def upgrade() -> None:
    op.create_table(
        "missions",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("name", sa.String(200), nullable=False),
        sa.Column("type", sa.String(32), nullable=False),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("reason", sa.Text(), nullable=False, server_default=""),
        sa.Column("robots", sa.JSON(), nullable=False),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("plan", sa.JSON(), nullable=False),
        sa.Column("progress", sa.JSON(), nullable=False),
        sa.Column("created_by", sa.String(160), nullable=False),
        sa.Column("created_at", sa.Double(), nullable=False),
        sa.Column("updated_at", sa.Double(), nullable=False),
        sa.Column("started_at", sa.Double(), nullable=True),
        sa.Column("ended_at", sa.Double(), nullable=True),
        sa.Column("run_s", sa.Double(), nullable=False, server_default="0"),
    )
    op.create_index("ix_missions_state", "missions", ["state"])
    op.create_table(
        "mission_transitions",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("mission_id", sa.String(36), nullable=False),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("from_state", sa.String(16), nullable=False),
        sa.Column("to_state", sa.String(16), nullable=False),
        sa.Column("actor", sa.String(160), nullable=False),
        sa.Column("reason", sa.Text(), nullable=False, server_default=""),
    )
    op.create_index("ix_mission_transitions_mission", "mission_transitions", ["mission_id"])
    op.create_table(
        "mission_events",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("mission_id", sa.String(36), nullable=False),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("kind", sa.String(32), nullable=False),
        sa.Column("robot_id", sa.String(64), nullable=True),
        sa.Column("detail", sa.JSON(), nullable=False),
    )
    op.create_index("ix_mission_events_mission", "mission_events", ["mission_id"])


def downgrade() -> None:
    op.drop_index("ix_mission_events_mission", table_name="mission_events")
    op.drop_table("mission_events")
    op.drop_index("ix_mission_transitions_mission", table_name="mission_transitions")
    op.drop_table("mission_transitions")
    op.drop_index("ix_missions_state", table_name="missions")
    op.drop_table("missions")
