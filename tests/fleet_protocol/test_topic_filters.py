"""Topic strings the server used to spell itself now come from fleet_protocol: shared-subscription filters
and the old framework's prefix."""

from __future__ import annotations

import pytest

from fleet_protocol import (
    LEGACY_COMMAND_TOPIC,
    LEGACY_SENSOR_FILTER,
    Topics,
    is_legacy_topic,
    shared_subscription,
)


def test_a_shared_subscription_filter() -> None:
    assert shared_subscription("ingest", Topics("lab/a").all_telemetry()) == "$share/ingest/lab/a/+/telemetry/+"
    assert shared_subscription("g-1", LEGACY_SENSOR_FILTER) == "$share/g-1/robot/sensor_data/+"


@pytest.mark.parametrize("group", ["", "a/b", "a+", "#", "x" * 65])
def test_a_group_that_would_change_the_filter_is_refused(group: str) -> None:
    with pytest.raises(ValueError, match="shared-subscription group"):
        shared_subscription(group, "fleet/+/status")


def test_legacy_topics_are_the_old_frameworks_and_no_others() -> None:
    assert is_legacy_topic(LEGACY_COMMAND_TOPIC) and is_legacy_topic("robot/sensor_data/position")
    assert not is_legacy_topic(Topics().status("robot"))  # a robot called "robot" under the fleet prefix
    assert not is_legacy_topic("robots/x") and not is_legacy_topic("fleet/robot/status")
