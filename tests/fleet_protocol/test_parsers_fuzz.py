"""Every MQTT payload parser in fleet_protocol, fuzzed: it returns a valid, finite model or raises
ProtocolError (the caller counts and drops it). No other exception escapes."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel

from fleet_protocol import (
    MAX_CAMERA_PAYLOAD_BYTES,
    MAX_JSON_PAYLOAD_BYTES,
    STREAM_SCHEMAS,
    CameraHeader,
    ProtocolError,
    decode_ack,
    decode_camera_frame,
    decode_command,
    decode_estop,
    decode_status,
    decode_telemetry,
    dumps,
    encode_camera_frame,
    parse_position_text,
)
from tests.support.strategies import JSON, dump, payloads

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _finite(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, BaseModel):
        return _finite(value.model_dump())
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list | tuple):
        return all(_finite(v) for v in value)
    return True


def _check(fn: Any, *args: Any) -> Any:
    try:
        result = fn(*args)
    except ProtocolError as exc:
        assert exc.reason and isinstance(exc.detail, str)
        return None
    assert _finite(result), result
    dumps(result) if isinstance(result, BaseModel) else None  # what was accepted can be re-encoded
    return result


@FUZZ
@given(payloads("status"))
def test_decode_status(payload):
    _check(decode_status, payload)


@FUZZ
@given(payloads("telemetry") | payloads("imu"), st.sampled_from([*STREAM_SCHEMAS, "battery", "custom_1"]))
def test_decode_telemetry(payload, stream):
    msg = _check(decode_telemetry, payload, stream)
    if msg is not None:
        assert 0 <= msg.seq < 2**63 and isinstance(msg.data, dict)
        if stream in STREAM_SCHEMAS:
            STREAM_SCHEMAS[stream].model_validate(msg.data)  # known streams: data matches the schema


@FUZZ
@given(payloads("command"))
def test_decode_command(payload):
    cmd = _check(decode_command, payload)
    if cmd is not None:
        assert 0 < cmd.ttl_s <= 60 and 1 <= len(cmd.id) <= 64


@FUZZ
@given(payloads("ack"))
def test_decode_ack(payload):
    _check(decode_ack, payload)


@FUZZ
@given(payloads("estop"))
def test_decode_estop(payload):
    msg = _check(decode_estop, payload)
    if payload == b"":
        assert msg is not None and msg.engaged is False  # a cleared retained e-stop is a release


@FUZZ
@given(
    st.one_of(
        st.binary(max_size=300),
        st.builds(lambda hdr, tail: b"MFC1" + hdr + tail, st.binary(min_size=4, max_size=4), st.binary(max_size=100)),
        st.builds(
            lambda header, jpeg: b"MFC1" + len(dump(header)).to_bytes(4, "big") + dump(header) + jpeg,
            JSON,
            st.binary(max_size=50),
        ),
    )
)
def test_decode_camera_frame(payload):
    _check(decode_camera_frame, payload)


@FUZZ
@given(
    st.one_of(
        JSON,
        st.text(max_size=60),
        st.binary(max_size=60),
        st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
    )
)
def test_parse_position_text(value):
    _check(parse_position_text, value)


@pytest.mark.parametrize(
    "decode",
    [decode_status, decode_ack, decode_command, decode_estop, lambda p: decode_telemetry(p, "position")],
)
def test_oversize_json_refused(decode):
    payload = b'{"ts": 1.0, "pad": "' + b"x" * MAX_JSON_PAYLOAD_BYTES + b'"}'
    with pytest.raises(ProtocolError) as info:
        decode(payload)
    assert info.value.reason == "oversize"


def test_oversize_camera_frame_refused():
    frame = encode_camera_frame(CameraHeader(frame_seq=1, ts=1.0, width=1, height=1), b"x" * MAX_CAMERA_PAYLOAD_BYTES)
    with pytest.raises(ProtocolError) as info:
        decode_camera_frame(frame)
    assert info.value.reason == "oversize"


@pytest.mark.parametrize(
    "payload",
    [
        b'{"ts": NaN, "seq": 1, "data": {}}',
        b'{"ts": 1e999, "seq": 1, "data": {}}',
        b'{"ts": 1.0, "seq": 1e30, "data": {}}',
        b'{"ts": 1.0, "seq": 99999999999999999999999, "data": {}}',
        b'{"ts": 1.0, "seq": -1, "data": {}}',
        b'{"ts": 1.0, "seq": true, "data": {}}',
        b'{"ts": "1.0", "seq": 1, "data": []}',
        b'{"ts": 1.0, "seq": 1.5, "data": {}}',
    ],
)
def test_bad_numbers_refused(payload):
    with pytest.raises(ProtocolError):
        decode_telemetry(payload, "battery")


def test_position_values_must_be_finite():
    for data in ({"x": 1e308 * 10, "y": 0}, {"x": "nan", "y": 0}, {"x": "inf", "y": 0}, {"x": 1, "y": "-Infinity"}):
        with pytest.raises(ProtocolError):
            decode_telemetry(dump({"ts": 1.0, "seq": 1, "data": data}), "position")
