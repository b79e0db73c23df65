"""Database operations of the e-stop's and the holds' newest state (``safety_latches``): one row per latch,
replaced by each new state. Saved through the writer (in order with the other writes, not behind telemetry);
read once at start."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import Connection, Engine, select
from sqlalchemy.dialects import postgresql, sqlite

from backend.models import SafetyLatchRow

#: ``kind`` of the fleet e-stop's row (its ``robot_id`` is "") and of a robot's hold
ESTOP = "estop"
HOLD = "hold"


def save_latch(
    kind: str,
    robot_id: str,
    engaged: bool,
    ts: float,
    latch_id: str | None,
    reason: str,
    source: str,
    stored_at: float,
) -> Callable[[Connection], None]:
    """Replace the latch's row with this state (every replica stores the states it adopted, in the broker's
    order, so they end on the same row)."""
    values: dict[str, Any] = {
        "kind": kind,
        "robot_id": robot_id,
        "engaged": engaged,
        "ts": ts,
        "latch_id": latch_id,
        "reason": reason[:500],
        "source": source[:120],
        "stored_at": stored_at,
    }

    def op(conn: Connection) -> None:
        ins = (postgresql.insert if conn.dialect.name == "postgresql" else sqlite.insert)(SafetyLatchRow).values(
            **values
        )
        update = {k: getattr(ins.excluded, k) for k in values if k not in ("kind", "robot_id")}
        conn.execute(ins.on_conflict_do_update(index_elements=["kind", "robot_id"], set_=update))

    return op


def load_latches(engine: Engine) -> list[dict[str, Any]]:
    """Every stored latch (the e-stop's and each robot's hold), engaged or released."""
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(select(SafetyLatchRow))]
