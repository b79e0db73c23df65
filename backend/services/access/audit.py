"""Who acts, and the audit trail of what they did: every lease take-over, command, site edit and run an
actor causes is one row of the append-only ``audit`` table, written through the writer like every write."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from backend.store import audit as store
from backend.store.writer import BatchWriter


@dataclass(frozen=True)
class Actor:
    """Who acts: for the audit trail (subject, name, token, address) and as a lease holder."""

    subject: str
    name: str
    token_id: str | None = None
    client: str = ""
    #: the lease holder: the principal, or with authentication off the browser tab / script's client id
    holder: str = ""

    @property
    def lease_holder(self) -> str:
        return self.holder or self.subject


class AuditService:
    """Append-only audit trail (``audit`` table), written through the writer like every other write."""

    def __init__(self, *, writer: BatchWriter) -> None:
        self._writer = writer
        self.recorded = 0

    def record(self, actor: Actor, action: str, robot_id: str | None, detail: dict[str, Any]) -> None:
        self._writer.submit(store.insert_audit(self.row(actor, action, robot_id, detail)), after_rows=False)

    def row(self, actor: Actor, action: str, robot_id: str | None, detail: dict[str, Any]) -> dict[str, Any]:
        """The row of an action (counted), for :meth:`record` or a write of its own (the e-stop's)."""
        self.recorded += 1
        return {
            "ts": time.time(),
            "actor": actor.subject[:160],
            "actor_name": actor.name[:160],
            "token_id": actor.token_id,
            "client": actor.client[:120],
            "action": action[:64],
            "robot_id": robot_id,
            "detail": detail,
        }
