"""The newest state of the fleet e-stop and of each robot's hold, restored at start and put back on a broker
that lost its retained messages (docs/safety.md, "The e-stop survives anything").

Revision ID: 0013
Revises: 0012
Create Date: 2026-11-29
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0013"
down_revision: str | None = "0012"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "safety_latches",
        sa.Column("kind", sa.String(16), primary_key=True),
        sa.Column("robot_id", sa.String(64), primary_key=True),
        sa.Column("engaged", sa.Boolean(), nullable=False),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("latch_id", sa.String(64), nullable=True),
        sa.Column("reason", sa.String(500), nullable=False),
        sa.Column("source", sa.String(120), nullable=False),
        sa.Column("stored_at", sa.Double(), nullable=False),
    )


def downgrade() -> None:
    op.drop_table("safety_latches")
