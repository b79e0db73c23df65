"""recv_ts: when the server received each telemetry message (its clock), beside the robot's ``ts``.

Nullable: rows stored before this revision have no receive time (and the history answers null for them).
No index: reads select and order by the robot's ``ts``; recv_ts rides along.

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-25
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0008"
down_revision: str | None = "0007"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # a plain ADD COLUMN (nullable, no default): no table rewrite on SQLite or PostgreSQL
    op.add_column("telemetry", sa.Column("recv_ts", sa.Double(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("telemetry") as batch:
        batch.drop_column("recv_ts")
