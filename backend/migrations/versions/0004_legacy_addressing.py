"""Robots on the old framework: which command topic each listens on (shared, as the seed's code, or own).

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("robots") as batch:
        batch.add_column(sa.Column("legacy_listens_on", sa.String(8), nullable=False, server_default="shared"))


def downgrade() -> None:
    with op.batch_alter_table("robots") as batch:
        batch.drop_column("legacy_listens_on")
