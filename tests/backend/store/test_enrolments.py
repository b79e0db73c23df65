"""Enrolment tokens in the real database (issue 29 #3): a token is used once, expires, is void once the robot
gets a newer one, and the database alone holds neither the token nor the password."""

from __future__ import annotations

import pytest
from sqlalchemy import Engine, text

from backend.store.enrolments import EnrolmentRefused, create_enrolment, redeem

PASSWORD = "the-robot-broker-password-0123456789"


def _make(engine: Engine, robot_id: str = "snail-5", now: float = 1000.0, ttl_s: float = 1800.0) -> str:
    return create_enrolment(engine, robot_id, PASSWORD, "mqtt://base.lab:1883", None, ttl_s, "test", now)


def _refused(engine: Engine, token: str, now: float) -> str:
    with pytest.raises(EnrolmentRefused) as caught:
        redeem(engine, token, "10.0.0.5", now)
    return caught.value.code


def test_a_token_works_once_and_the_database_keeps_no_secret(engine: Engine) -> None:
    token = _make(engine)
    with engine.connect() as conn:
        stored = " ".join(str(v) for row in conn.execute(text("SELECT * FROM enrolments")) for v in row)
    assert token not in stored and PASSWORD not in stored and PASSWORD.encode().hex() not in stored
    got = redeem(engine, token, "10.0.0.5", 1001.0)
    assert (got.robot_id, got.password, got.broker) == ("snail-5", PASSWORD, "mqtt://base.lab:1883")
    assert _refused(engine, token, 1002.0) == "enrolment_used"
    with engine.connect() as conn:
        assert conn.execute(text("SELECT password_sealed, used_by FROM enrolments")).one() == ("", "10.0.0.5")
    assert _refused(engine, "fle_" + "x" * 43, 1002.0) == "enrolment_unknown"


def test_a_token_expires_and_a_newer_one_replaces_it(engine: Engine) -> None:
    old = _make(engine, now=1000.0, ttl_s=60.0)
    assert _refused(engine, old, 1060.0) == "enrolment_expired"
    first = _make(engine, now=2000.0)
    second = _make(engine, now=2001.0)  # `robots add` again: a new password, the first token's is dead
    other = _make(engine, robot_id="snail-6", now=2002.0)
    assert _refused(engine, first, 2003.0) == "enrolment_replaced"
    assert redeem(engine, second, "10.0.0.5", 2003.0).robot_id == "snail-5"
    assert redeem(engine, other, "10.0.0.6", 2003.0).robot_id == "snail-6"
