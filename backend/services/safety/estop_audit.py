"""The fleet e-stop in the audit trail, however it came.

- Through this server's API: the caller (the route's actor) with ``reason`` and ``source`` as the client gave
  them.
- Through the broker: another client published ``fleet/estop`` (``fleet-agent estop``, a base-station button,
  anything with the ``fleet-estop`` account). The broker cannot say who published, so the row's actor is
  ``broker`` (client ``mqtt``) and its name the message's ``source``: what the sender says it is.

Engaging is never refused or delayed by this: the message is on the broker before anything is written, and
the row is written with the state's store, in its transaction (store/latches.py). An engage while the e-stop
is already engaged adds no row: the e-stop's row counts it (store/audit.py ``record_estop``).

Exactly once with replicas: each replica sees every e-stop on the broker. One made through a replica's API
carries an id signed with FLEET_SECRET_KEY (replicas share it, as they share sessions), so the others know it
is audited already and a client without the key cannot pass its own e-stop off as one; a broker e-stop is
audited by the replica whose store changes the latch's row first.
"""

from __future__ import annotations

import hashlib
import hmac
import uuid
from typing import Any

from sqlalchemy import Connection

from backend.services.access.audit import Actor
from backend.store import audit as store
from backend.store.latches import AfterStore
from fleet_protocol import EStop

#: the audit trail's actor of an e-stop that came through the broker
BROKER_SUBJECT = "broker"


def _tag(key: bytes, nonce: str, ts: float, engaged: bool) -> str:
    return hmac.new(key, f"estop|{nonce}|{ts!r}|{int(engaged)}".encode(), hashlib.sha256).hexdigest()[:24]


def signed_id(key: bytes, ts: float, engaged: bool) -> str:
    """The id of an e-stop this server publishes: random, and signed together with its time and state (a copy
    with another time or state does not verify)."""
    nonce = uuid.uuid4().hex
    return f"{nonce}.{_tag(key, nonce, ts, engaged)}"


def made_by_a_server(key: bytes, msg: EStop) -> bool:
    """Whether a replica (anyone holding the key) published this state through its API, and audited it."""
    nonce, dot, tag = (msg.id or "").partition(".")
    return bool(nonce and dot) and hmac.compare_digest(tag, _tag(key, nonce, msg.ts, msg.engaged))


def broker_actor(msg: EStop) -> Actor:
    return Actor(subject=BROKER_SUBJECT, name=f"broker: {msg.source or 'no source given'}", client="mqtt")


def detail(msg: EStop, source: str) -> dict[str, Any]:
    return {"id": msg.id, "reason": msg.reason, "source": source}


def audit_after_store(row: dict[str, Any], always: bool) -> AfterStore:
    """Writes ``row`` in the store's transaction: ``always`` (this server's API), or only when this replica's
    store changed the latch (a broker e-stop: the first replica to store it); an engage while engaged is
    counted in the e-stop's row instead."""

    def write(conn: Connection, first: bool, was_engaged: bool) -> None:
        if always or first:
            store.record_estop(conn, row, repeat=row["action"] == "estop" and was_engaged)

    return write
