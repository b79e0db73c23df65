"""Control leases (one operator drives a robot) and the append-only audit trail.

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-25
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BigId = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def upgrade() -> None:
    op.create_table(
        "leases",
        sa.Column("robot_id", sa.String(64), primary_key=True),
        sa.Column("holder", sa.String(160), nullable=False),
        sa.Column("holder_name", sa.String(160), nullable=False),
        sa.Column("acquired_at", sa.Double(), nullable=False),
        sa.Column("last_drive", sa.Double(), nullable=False),
        sa.Column("via", sa.String(64), nullable=False, server_default=""),
    )
    op.create_table(
        "audit",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("actor", sa.String(160), nullable=False),
        sa.Column("actor_name", sa.String(160), nullable=False),
        sa.Column("token_id", sa.String(32), nullable=True),
        sa.Column("client", sa.String(120), nullable=False, server_default=""),
        sa.Column("action", sa.String(64), nullable=False),
        sa.Column("robot_id", sa.String(64), nullable=True),
        sa.Column("detail", sa.JSON(), nullable=False),
    )
    op.create_index("ix_audit_ts", "audit", ["ts"])
    op.create_index("ix_audit_action_ts", "audit", ["action", "ts"])


def downgrade() -> None:
    op.drop_index("ix_audit_action_ts", table_name="audit")
    op.drop_index("ix_audit_ts", table_name="audit")
    op.drop_table("audit")
    op.drop_table("leases")
