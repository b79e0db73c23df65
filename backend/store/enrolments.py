"""Database operations of robot enrolments (``enrolments``): made by the CLI, used once by ``POST
/api/enrol``. Rare writes straight on the engine (like the accounts'); the use is one conditional UPDATE, so of
two replicas (or two tries) answering the same token exactly one hands out the password."""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import Engine, delete, insert, select, update

from backend.core.enrolment import new_token, seal, token_hash, unseal
from backend.models import EnrolmentRow

#: used, expired and replaced rows are kept this long (a late try still hears "used"), then deleted
KEEP_S = 7 * 86400
REPLACED = "replaced"


@dataclass(frozen=True)
class Redeemed:
    robot_id: str
    password: str
    broker: str | None
    tls_ca: str | None


class EnrolmentRefused(Exception):
    """``code``: ``enrolment_unknown`` (404), ``enrolment_used``, ``enrolment_replaced`` or
    ``enrolment_expired`` (410)."""

    def __init__(self, code: str, detail: str) -> None:
        super().__init__(detail)
        self.code = code
        self.detail = detail
        self.status_code = 404 if code == "enrolment_unknown" else 410


def create_enrolment(
    engine: Engine,
    robot_id: str,
    password: str,
    broker: str | None,
    tls_ca: str | None,
    ttl_s: float,
    created_by: str,
    now: float,
) -> str:
    """A new token for ``robot_id`` (returned, never stored); the robot's earlier unused tokens are void
    (they carry a password the broker no longer takes)."""
    token = new_token()
    with engine.begin() as conn:
        conn.execute(delete(EnrolmentRow).where(EnrolmentRow.expires_at < now - KEEP_S))
        conn.execute(
            update(EnrolmentRow)
            .where(EnrolmentRow.robot_id == robot_id, EnrolmentRow.used_at.is_(None))
            .values(used_at=now, used_by=REPLACED, password_sealed="")
        )
        conn.execute(
            insert(EnrolmentRow).values(
                token_hash=token_hash(token),
                robot_id=robot_id,
                password_sealed=seal(token, password),
                broker=broker,
                tls_ca=tls_ca,
                created_at=now,
                created_by=created_by[:160],
                expires_at=now + ttl_s,
                used_at=None,
                used_by=None,
            )
        )
    return token


def redeem(engine: Engine, token: str, client: str, now: float) -> Redeemed:
    """Use the token once: the robot's password and pin, or EnrolmentRefused."""
    key = token_hash(token)
    with engine.begin() as conn:
        row = conn.execute(select(EnrolmentRow).where(EnrolmentRow.token_hash == key)).mappings().one_or_none()
        if row is None:
            raise EnrolmentRefused("enrolment_unknown", "no such enrolment token")
        if row["used_by"] == REPLACED:
            raise EnrolmentRefused("enrolment_replaced", "a newer enrolment of this robot replaced this token")
        if row["used_at"] is not None:
            raise EnrolmentRefused("enrolment_used", "this enrolment token was used already")
        if row["expires_at"] <= now:
            raise EnrolmentRefused("enrolment_expired", "this enrolment token has expired")
        taken = conn.execute(
            update(EnrolmentRow)
            .where(EnrolmentRow.token_hash == key, EnrolmentRow.used_at.is_(None))
            .values(used_at=now, used_by=client[:120], password_sealed="")
        )
        if taken.rowcount != 1:  # another replica (or try) took it between the read and this update
            raise EnrolmentRefused("enrolment_used", "this enrolment token was used already")
        return Redeemed(
            robot_id=row["robot_id"],
            password=unseal(token, row["password_sealed"]),
            broker=row["broker"],
            tls_ca=row["tls_ca"],
        )
