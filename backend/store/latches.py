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

#: run in the store's transaction: (connection, whether this store changed the row, whether the row held
#: another state that was engaged before it)
AfterStore = Callable[[Connection, bool, bool], None]


def save_latch(
    kind: str,
    robot_id: str,
    engaged: bool,
    ts: float,
    latch_id: str | None,
    reason: str,
    source: str,
    stored_at: float,
    after: AfterStore | None = None,
) -> Callable[[Connection], bool]:
    """Replace the latch's row with this state (every replica stores the states it adopted, in the broker's
    order, so they end on the same row); returns whether this store changed it (False: the row holds this
    very state already, stored by another replica first). ``after`` runs in the same transaction, the row
    locked (PostgreSQL), so that replicas storing one state take turns (the e-stop's audit row)."""
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

    def op(conn: Connection) -> bool:
        key = (SafetyLatchRow.kind == kind, SafetyLatchRow.robot_id == robot_id)
        before = conn.execute(
            select(SafetyLatchRow.engaged, SafetyLatchRow.ts, SafetyLatchRow.latch_id).where(*key).with_for_update()
        ).first()
        same = before is not None and (before.engaged, before.ts, before.latch_id) == (engaged, ts, latch_id)
        if not same:
            ins = (postgresql.insert if conn.dialect.name == "postgresql" else sqlite.insert)(SafetyLatchRow).values(
                **values
            )
            update = {k: getattr(ins.excluded, k) for k in values if k not in ("kind", "robot_id")}
            conn.execute(ins.on_conflict_do_update(index_elements=["kind", "robot_id"], set_=update))
        if after is not None:
            after(conn, not same, before is not None and not same and bool(before.engaged))
        return not same

    return op


def load_latches(engine: Engine) -> list[dict[str, Any]]:
    """Every stored latch (the e-stop's and each robot's hold), engaged or released."""
    with engine.connect() as conn:
        return [dict(r._mapping) for r in conn.execute(select(SafetyLatchRow))]
