"""Single-use robot enrolment tokens (issue 29 #3): ``fleet-server robots add`` stores one, ``POST
/api/enrol`` exchanges it once for the robot's broker password and the base station's pin.

Revision ID: 0014
Revises: 0013
Create Date: 2026-11-29
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0014"
down_revision: str | None = "0013"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "enrolments",
        sa.Column("token_hash", sa.String(64), primary_key=True),
        sa.Column("robot_id", sa.String(64), nullable=False),
        sa.Column("password_sealed", sa.String(600), nullable=False),
        sa.Column("broker", sa.String(500), nullable=True),
        sa.Column("tls_ca", sa.Text(), nullable=True),
        sa.Column("created_at", sa.Double(), nullable=False),
        sa.Column("created_by", sa.String(160), nullable=False),
        sa.Column("expires_at", sa.Double(), nullable=False),
        sa.Column("used_at", sa.Double(), nullable=True),
        sa.Column("used_by", sa.String(120), nullable=True),
    )
    op.create_index("ix_enrolments_robot_id", "enrolments", ["robot_id"])


def downgrade() -> None:
    op.drop_index("ix_enrolments_robot_id", table_name="enrolments")
    op.drop_table("enrolments")
