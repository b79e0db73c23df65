"""Hypothesis: no inbound MQTT message, however malformed, makes the dispatcher fail internally."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from backend.comms.mqtt_bridge import InboundMessage
from backend.core.rejects import InboundRejects
from backend.services.dispatcher import Dispatcher
from fleet_protocol import Topics
from tests.backend.helpers import dispatcher_rig

T = Topics()
ROBOTS = st.sampled_from(["r1", "r-2", "bad id", "x" * 70, "", "+", "ü"])
STREAMS = st.sampled_from(["position", "imu", "apriltag", "lighthouse_geometry", "battery", "bad$", ""])
JSONISH = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12,
)


@st.composite
def messages(draw: st.DrawFn) -> InboundMessage:
    robot, stream = draw(ROBOTS), draw(STREAMS)
    topic = draw(
        st.sampled_from(
            [
                f"fleet/{robot}/status",
                f"fleet/{robot}/telemetry/{stream}",
                f"fleet/{robot}/ack",
                "fleet/estop",
                f"fleet/{robot}/cmd",
                f"fleet/{robot}/what",
                "robot/sensor_data/position",
                "robot/sensor_data/imu",
                "robot/sensor_data/apriltag",
                "robot/sensor_data/other",
                "other/topic",
            ]
        )
    )
    base = draw(
        st.sampled_from(
            [
                {"online": True, "ts": 1.0, "capabilities": {"commands": ["stop"]}},
                {"ts": 1.0, "seq": 1, "data": {"x": 1.0, "y": 2.0}},
                {"id": "c", "status": "done", "ts": 1.0},
                {"ts": 1.0, "engaged": True, "id": "e"},
                {"robot_id": "snail", "position": "1,2,3"},
                {"robot_id": "snail", "imu_data": {"accel": [0, 0, 1], "gyro": [0, 0, 0]}},
                {},
            ]
        )
    )
    mutated = {
        **base,
        **draw(
            st.dictionaries(
                st.sampled_from(
                    [
                        "ts",
                        "seq",
                        "data",
                        "online",
                        "id",
                        "status",
                        "position",
                        "robot_id",
                        "engaged",
                        "capabilities",
                    ]
                ),
                JSONISH,
                max_size=3,
            )
        ),
    }
    payload = draw(
        st.one_of(
            st.just(json.dumps(mutated).encode()),
            st.binary(max_size=64),
            st.builds(lambda v: json.dumps(v).encode(), JSONISH),
        )
    )
    return InboundMessage(topic, payload, draw(st.booleans()), time.time())


@pytest.fixture(scope="module")
def dispatcher(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Dispatcher, InboundRejects]]:
    with dispatcher_rig(Path(tmp_path_factory.mktemp("fuzz")) / "fuzz.db") as (dispatcher, _registry, rejects):
        yield dispatcher, rejects


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(batch=st.lists(messages(), min_size=1, max_size=5))
def test_dispatcher_never_fails_internally(dispatcher, batch):
    d, rejects = dispatcher
    d.handle_batch(batch)
    assert rejects.count("internal_error") == 0, rejects.snapshot()
