"""The rules that decide, after a (re)connection, whose e-stop or hold wins: the server's stored state or the
broker's retained one (backend/services/safety/latches.py; docs/safety.md, "The e-stop survives anything").
The same rules run end to end in tests/system/test_estop_survives.py."""

from __future__ import annotations

import pytest

from backend.services.safety.latches import lost_by_broker, replaces

OLD, NEW = (100.0, "a"), (200.0, "b")


@pytest.mark.parametrize(
    ("ours", "ours_engaged", "theirs", "theirs_engaged", "taken"),
    [
        (None, False, OLD, True, True),  # nothing stored yet: the broker's state
        (None, False, OLD, False, True),
        (OLD, False, NEW, True, True),  # a newer latch (fleet-agent estop while the server was away)
        (OLD, True, NEW, False, True),  # a newer release someone pressed on the broker
        (NEW, True, OLD, False, False),  # an older release (a broker restored from an older save): ignored
        (NEW, True, OLD, True, False),  # an older latch: ours is newer, ours stays (and is put back)
        (NEW, False, OLD, True, True),  # an older latch against our release: the latch stands
        (NEW, False, OLD, False, False),  # an older release: nothing to take
        (NEW, True, NEW, True, False),  # the same state (our own echo)
        ((100.0, "b"), True, (100.0, "a"), False, False),  # same ts: the id decides
        ((100.0, "a"), True, (100.0, "b"), False, True),
    ],
)
def test_a_newer_state_or_any_latch_from_the_broker_is_taken(ours, ours_engaged, theirs, theirs_engaged, taken):
    assert replaces(ours, ours_engaged, theirs, theirs_engaged) is taken


@pytest.mark.parametrize(
    ("ours", "ours_engaged", "on_broker", "lost"),
    [
        (NEW, True, None, True),  # a broker that holds nothing (restarted empty)
        (NEW, True, OLD, True),  # a broker that holds an older state
        (NEW, True, NEW, False),  # it holds ours
        (OLD, True, NEW, False),  # it holds a newer one (taken by replaces())
        (NEW, False, None, False),  # a release is never put back
        (NEW, False, OLD, False),
        (None, False, None, False),  # nothing stored
    ],
)
def test_only_a_latch_newer_than_what_the_broker_holds_is_put_back(ours, ours_engaged, on_broker, lost):
    assert lost_by_broker(ours, ours_engaged, on_broker) is lost
