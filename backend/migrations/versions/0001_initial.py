"""Initial schema: robots, telemetry, commands, command_acks, events.

Revision ID: 0001
Revises:
Create Date: 2025-01-01
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BigId = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def upgrade() -> None:
    op.create_table(
        "robots",
        sa.Column("id", sa.String(64), primary_key=True),
        sa.Column("legacy", sa.Boolean(), nullable=False, server_default=sa.false()),
        sa.Column("agent_version", sa.String(120), nullable=False, server_default=""),
        sa.Column("capabilities", sa.JSON(), nullable=False),
        sa.Column("first_seen", sa.Double(), nullable=False),
        sa.Column("last_seen", sa.Double(), nullable=True),
        sa.Column("online", sa.Boolean(), nullable=False, server_default=sa.false()),
    )
    op.create_table(
        "telemetry",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("robot_id", sa.String(64), nullable=False),
        sa.Column("stream", sa.String(64), nullable=False),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("seq", sa.BigInteger(), nullable=False),
        sa.Column("x", sa.Double(), nullable=True),
        sa.Column("y", sa.Double(), nullable=True),
        sa.Column("z", sa.Double(), nullable=True),
        sa.Column("yaw", sa.Double(), nullable=True),
        sa.Column("payload", sa.Text(), nullable=False),
        sa.UniqueConstraint("robot_id", "stream", "seq", "ts", name="uq_telemetry_robot_stream_seq_ts"),
    )
    op.create_index("ix_telemetry_robot_stream_ts", "telemetry", ["robot_id", "stream", "ts"])
    op.create_table(
        "commands",
        sa.Column("id", sa.String(64), primary_key=True),
        sa.Column("robot_id", sa.String(64), nullable=False),
        sa.Column("command", sa.String(64), nullable=False),
        sa.Column("args", sa.JSON(), nullable=False),
        sa.Column("source", sa.String(120), nullable=False, server_default="rest"),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("ttl_s", sa.Double(), nullable=False),
        sa.Column("status", sa.String(16), nullable=False),
        sa.Column("reason", sa.Text(), nullable=False, server_default=""),
        sa.Column("updated_at", sa.Double(), nullable=False),
    )
    op.create_index("ix_commands_robot_ts", "commands", ["robot_id", "ts"])
    op.create_table(
        "command_acks",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("command_id", sa.String(64), nullable=False),
        sa.Column("status", sa.String(16), nullable=False),
        sa.Column("reason", sa.Text(), nullable=False, server_default=""),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("received_ts", sa.Double(), nullable=False),
    )
    op.create_index("ix_command_acks_command_id", "command_acks", ["command_id"])
    op.create_table(
        "events",
        sa.Column("id", BigId, primary_key=True, autoincrement=True),
        sa.Column("ts", sa.Double(), nullable=False),
        sa.Column("kind", sa.String(32), nullable=False),
        sa.Column("robot_id", sa.String(64), nullable=True),
        sa.Column("detail", sa.JSON(), nullable=False),
    )
    op.create_index("ix_events_ts", "events", ["ts"])
    op.create_index("ix_events_robot_ts", "events", ["robot_id", "ts"])


def downgrade() -> None:
    op.drop_table("events")
    op.drop_table("command_acks")
    op.drop_table("commands")
    op.drop_table("telemetry")
    op.drop_table("robots")
