"""The server's Dispatcher.handle_batch under hostile MQTT input (real services, SQLite, writer thread):
no exception escapes, every bad message is counted, a refused message changes nothing (the last good
value stays) and a message about one robot never changes another."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import orjson
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from backend.comms.mqtt_bridge import InboundMessage
from backend.core.rejects import InboundRejects
from backend.services.dispatcher import Dispatcher
from backend.services.fleet.registry import Registry
from fleet_protocol import (
    MAX_CAMERA_PAYLOAD_BYTES,
    MAX_JSON_PAYLOAD_BYTES,
    ProtocolError,
    TopicKind,
    Topics,
    decode_ack,
    decode_camera_frame,
    decode_estop,
    decode_status,
    decode_telemetry,
    encode_telemetry,
)
from tests.backend.helpers import dispatcher_rig
from tests.support.strategies import JSON, VALID, dump, mutated, payloads

T = Topics()
TARGETS = ["r1", "r2"]  # fuzzed robots; "keeper" is never addressed by topic
LEGACY_ROBOT = "legacy-1"  # the one robot registered as on the old framework
ROBOT_IDS = st.sampled_from([*TARGETS, "bad id", "x" * 70, "", "+", "#", "ü"])


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Dispatcher, Registry, InboundRejects]]:
    with dispatcher_rig(Path(tmp_path_factory.mktemp("fuzz-state")) / "fuzz.db", camera=True) as (
        dispatcher,
        registry,
        rejects,
    ):
        now = time.time()
        for rid in [*TARGETS, "keeper"]:  # every robot starts online with a known position
            dispatcher.handle_batch(
                [
                    InboundMessage(T.status(rid), dump(VALID["status"] | {"ts": now}), True, now),
                    InboundMessage(
                        T.telemetry(rid, "position"), encode_telemetry(1, {"x": 1.0, "y": 2.0}, now), False, now
                    ),
                ]
            )
        assert registry.get("keeper") is not None and registry.get("keeper").position is not None  # type: ignore[union-attr]
        registry.ensure(LEGACY_ROBOT, now).legacy = True  # registered by an admin: the one the old topics speak for
        yield dispatcher, registry, rejects


def _state(registry: Registry) -> dict[str, Any]:
    return {
        rid: (
            st.online,
            st.position.model_dump() if st.position else None,
            st.capabilities.model_dump(),
            st.estop,
            {k: v.model_dump() for k, v in st.sensors.items()},
            dict(st.retained),
            {k: (v.count, v.last_seq) for k, v in st.streams.items()},
            st.agent_version,
        )
        for rid, st in registry.robots.items()
    }


@st.composite
def messages(draw: st.DrawFn) -> InboundMessage:
    rid = draw(ROBOT_IDS)
    stream = draw(st.sampled_from(["position", "imu", "apriltag", "lighthouse_geometry", "battery", "bad$"]))
    topic, kind = draw(
        st.sampled_from(
            [
                (f"fleet/{rid}/status", "status"),
                (f"fleet/{rid}/telemetry/{stream}", "telemetry"),
                (f"fleet/{rid}/telemetry/{stream}", "imu"),
                (f"fleet/{rid}/ack", "ack"),
                (f"fleet/{rid}/camera", "ack"),
                (f"fleet/{rid}/cmd", "command"),
                (f"fleet/{rid}/nope", "status"),
                ("fleet/estop", "estop"),
                ("robot/sensor_data/position", "telemetry"),
                ("robot/sensor_data/imu", "imu"),
                ("elsewhere/x", "ack"),
            ]
        )
    )
    if topic.startswith("robot/"):
        payload = draw(
            st.builds(
                dump,
                st.fixed_dictionaries(
                    {"robot_id": st.sampled_from(["r1", LEGACY_ROBOT, "ghost", "bad id", 5])},
                    optional={"position": JSON | st.just("1,2,3"), "imu_data": JSON},
                ),
            )
            | st.binary(max_size=50)
        )
    else:
        payload = draw(payloads(kind))
    return InboundMessage(topic, payload, draw(st.booleans()), time.time())


def _valid(msg: InboundMessage) -> bool | None:
    """Whether the server should accept a ``fleet/`` message, decided by fleet_protocol alone (None: a
    legacy or foreign topic, not judged here)."""
    if not msg.topic.startswith("fleet/"):
        return None
    try:
        parsed = T.parse(msg.topic)
        if parsed.kind is TopicKind.TELEMETRY:
            assert parsed.stream is not None
            decode_telemetry(msg.payload, parsed.stream)
        elif parsed.kind is TopicKind.STATUS:
            if msg.payload:  # empty: a retained status being cleared
                decode_status(msg.payload)
        elif parsed.kind is TopicKind.ACK:
            decode_ack(msg.payload)
        elif parsed.kind is TopicKind.ESTOP:
            decode_estop(msg.payload)
        elif parsed.kind is TopicKind.CAMERA:
            decode_camera_frame(msg.payload)
        else:
            return False  # the server never takes commands
    except ProtocolError:
        return False
    return True


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(batch=st.lists(messages(), min_size=1, max_size=6))
def test_refused_messages_change_nothing_and_robots_are_isolated(rig, batch):
    dispatcher, registry, rejects = rig
    for msg in batch:
        before, total = _state(registry), rejects.snapshot()["total"]
        dispatcher.handle_batch([msg])  # must not raise
        after = _state(registry)
        assert rejects.count("internal_error") == 0, rejects.snapshot()
        valid = _valid(msg)
        if valid is not None:  # every bad message is counted, exactly once; a good one never
            assert rejects.snapshot()["total"] == total + (0 if valid else 1), (msg.topic, msg.payload[:200])
        if rejects.snapshot()["total"] != total:  # refused: nothing changed anywhere (last good value kept)
            assert after == before, (msg.topic, msg.payload[:200])
        if msg.topic.startswith("robot/"):  # the old topics speak only for the registered robot
            assert {rid: v for rid, v in after.items() if rid != LEGACY_ROBOT} == {
                rid: v for rid, v in before.items() if rid != LEGACY_ROBOT
            }, (msg.topic, msg.payload[:200])
        addressed = msg.topic.split("/")[1] if msg.topic.startswith("fleet/") else None
        if addressed is not None and addressed != "estop":
            for rid in before:  # robots the message was not about are untouched
                if rid != addressed:
                    assert after[rid] == before[rid], (rid, msg.topic)
        assert after["keeper"][1] is not None or before["keeper"][1] is None
        for st_ in registry.robots.values():
            if st_.position is not None:
                assert all(math.isfinite(v) for v in (st_.position.x, st_.position.y, st_.position.z))


def test_oversize_messages_counted_and_dropped(rig):
    dispatcher, registry, rejects = rig
    before = _state(registry)
    big_json = b'{"ts": 1.0, "seq": 9, "data": {"x": 1, "y": 2, "pad": "' + b"x" * MAX_JSON_PAYLOAD_BYTES + b'"}}'
    n = rejects.count("oversize")
    dispatcher.handle_batch(
        [
            InboundMessage(T.telemetry("r1", "position"), big_json, False, time.time()),
            InboundMessage(T.status("r1"), big_json, True, time.time()),
            InboundMessage(T.ack("r1"), big_json, False, time.time()),
            InboundMessage("fleet/estop", big_json, True, time.time()),
            InboundMessage(T.camera("r1"), b"MFC1" + b"\0" * MAX_CAMERA_PAYLOAD_BYTES, False, time.time()),
            InboundMessage("robot/sensor_data/position", big_json, False, time.time()),
        ]
    )
    assert rejects.count("oversize") == n + 6
    assert _state(registry) == before


def test_a_good_message_after_garbage_still_applies(rig):
    dispatcher, registry, _ = rig
    now = time.time()
    dispatcher.handle_batch(
        [
            InboundMessage(T.telemetry("keeper", "position"), b"\xff garbage", False, now),
            InboundMessage(
                T.telemetry("keeper", "position"),
                orjson.dumps({"ts": now, "seq": 10**6, "data": {"x": 3.5, "y": -1.0}}),
                False,
                now,
            ),
        ]
    )
    pos = registry.get("keeper").position  # type: ignore[union-attr]
    assert pos is not None and (pos.x, pos.y) == (3.5, -1.0)


def test_mutated_status_never_crashes(rig):
    dispatcher, _, rejects = rig

    @settings(max_examples=100, deadline=None)
    @given(mutated(VALID["status"]))
    def inner(status):
        dispatcher.handle_batch([InboundMessage(T.status("r2"), dump(status), True, time.time())])
        assert rejects.count("internal_error") == 0

    inner()


def test_bad_messages_logged_at_a_limited_rate(rig, caplog):
    dispatcher, _, rejects = rig
    caplog.set_level("WARNING", logger="backend.rejects")
    n = rejects.count("bad_json")
    dispatcher.handle_batch([InboundMessage(T.telemetry("r1", "imu"), b"{nope", False, time.time())] * 300)
    assert rejects.count("bad_json") == n + 300
    assert len([r for r in caplog.records if r.name == "backend.rejects"]) <= 1
