"""The one rate-limited logger: the server's reject counter and ingest, the agent's reject counter."""

from __future__ import annotations

import logging

import pytest

from fleet_common import RateLimitedLogger
from robot_agent.util import RejectCounter


def test_one_warning_per_key_per_interval_and_the_next_one_says_how_many_were_suppressed(
    caplog: pytest.LogCaptureFixture,
) -> None:
    log = logging.getLogger("fleet.test.ratelimit")
    limited = RateLimitedLogger(log, interval_s=3600)
    with caplog.at_level(logging.WARNING, logger=log.name):
        assert limited.warning("a", "bad %s", "one") == 0
        assert limited.warning("a", "bad %s", "two") is None
        assert limited.warning("a", "bad %s", "three") is None
        assert limited.warning("b", "other %s", "key") == 0  # keys are limited apart
    assert [r.getMessage() for r in caplog.records] == ["bad one", "other key"]
    caplog.clear()
    limited._interval = 0.0  # the interval has passed
    with caplog.at_level(logging.WARNING, logger=log.name):
        assert limited.warning("a", "bad %s", "four") == 2
    assert [r.getMessage() for r in caplog.records] == ["bad four (2 similar suppressed)"]


def test_the_agents_reject_counter_counts_every_reject_and_logs_the_first(caplog: pytest.LogCaptureFixture) -> None:
    log = logging.getLogger("fleet.test.agent-rejects")
    rejects = RejectCounter(log)
    with caplog.at_level(logging.WARNING, logger=log.name):
        for i in range(5):
            rejects.reject("bad_args", f"move_forward {i}")
        rejects.reject("expired", "stop c1")
    assert rejects.counts == {"bad_args": 5, "expired": 1} and rejects.total == 6
    assert [r.getMessage() for r in caplog.records] == [
        "rejected bad_args: move_forward 0 [total 1]",
        "rejected expired: stop c1 [total 1]",
    ]
