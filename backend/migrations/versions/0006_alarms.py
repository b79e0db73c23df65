"""Alarms (active -> acknowledged -> cleared), their transitions, and admins' rule thresholds.

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-25
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BigId = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def upgrade() -> None:
    op.create_table(
        "alarms",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("robot_key", sa.String(64), nullable=False),
        sa.Column("kind", sa.String(48), nullable=False),
        sa.Column("severity", sa.String(16), nullable=False),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("message", sa.Text(), nullable=False, server_default=""),
        sa.Column("detail", sa.JSON(), nullable=False),
        sa.Column("raised_at", sa.Double(), nullable=False),
        sa.Column("acked_at", sa.Double(), nullable=True),
        sa.Column("acked_by", sa.String(160), nullable=True),
        sa.Column("cleared_at", sa.Double(), nullable=True),
    )
    op.create_index("ix_alarms_state_raised", "alarms", ["state", "raised_at"])
    op.create_index(
        "uq_alarms_open",
        "alarms",
        ["robot_key", "kind"],
        unique=True,
        sqlite_where=sa.text("cleared_at IS NULL"),
        postgresql_where=sa.text("cleared_at IS NULL"),
    )
    op.create_table(
        "alarm_transitions",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("alarm_id", sa.BigInteger(), nullable=False),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("by", sa.String(160), nullable=False),
    )
    op.create_index("ix_alarm_transitions_alarm", "alarm_transitions", ["alarm_id"])
    op.create_table(
        "alarm_rules",
        sa.Column("kind", sa.String(48), primary_key=True),
        sa.Column("enabled", sa.Boolean(), nullable=False),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("updated_at", sa.Double(), nullable=False),
        sa.Column("updated_by", sa.String(160), nullable=False, server_default=""),
    )


def downgrade() -> None:
    op.drop_table("alarm_rules")
    op.drop_index("ix_alarm_transitions_alarm", table_name="alarm_transitions")
    op.drop_table("alarm_transitions")
    op.drop_index("uq_alarms_open", table_name="alarms")
    op.drop_index("ix_alarms_state_raised", table_name="alarms")
    op.drop_table("alarms")
