"""Raw telemetry rows (the rollup tables are in ``backend.models.aggregates``)."""

from __future__ import annotations

from sqlalchemy import BigInteger, Double, Index, String, Text, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from backend.models.base import Base, BigId


class TelemetryRow(Base):
    __tablename__ = "telemetry"
    __table_args__ = (
        UniqueConstraint("robot_id", "stream", "seq", "ts", name="uq_telemetry_robot_stream_seq_ts"),
        # covering: a history GROUP BY over positions reads the index alone (migration 0015)
        Index("ix_telemetry_robot_stream_ts_xyz", "robot_id", "stream", "ts", "x", "y", "z"),
    )

    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    robot_id: Mapped[str] = mapped_column(String(64))
    stream: Mapped[str] = mapped_column(String(64))
    ts: Mapped[float] = mapped_column(Double)
    seq: Mapped[int] = mapped_column(BigInteger)
    x: Mapped[float | None] = mapped_column(Double, nullable=True)
    y: Mapped[float | None] = mapped_column(Double, nullable=True)
    z: Mapped[float | None] = mapped_column(Double, nullable=True)
    yaw: Mapped[float | None] = mapped_column(Double, nullable=True)
    payload: Mapped[str] = mapped_column(Text)
    #: when the server received the message (server clock; ``ts`` is the robot's): clock trouble shows as
    #: their difference, and a plot can use either. Null for rows stored before migration 0008.
    recv_ts: Mapped[float | None] = mapped_column(Double, nullable=True)
