"""Each site version carries the robots' safety filter settings (issue 31: robots never collide): enabled, margin,
creep speed (fleet_protocol.AvoidanceSettings). Versions stored before have none (null): they read as the
defaults.

Revision ID: 0017
Revises: 0016
Create Date: 2026-11-29
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0017"
down_revision: str | None = "0016"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("site_versions") as batch:
        batch.add_column(sa.Column("avoidance", sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("site_versions") as batch:
        batch.drop_column("avoidance")
