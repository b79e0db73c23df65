"""Hypothesis strategies for hostile MQTT payloads: random bytes, JSON of the wrong shape and types,
NaN/Infinity tokens, huge numbers, unknown fields, truncation."""

from __future__ import annotations

import json
from typing import Any

from hypothesis import strategies as st

SCALARS = (
    st.none()
    | st.booleans()
    | st.integers()  # unbounded: 2**70 and beyond
    | st.sampled_from([0, -1, 2**63, -(2**63) - 1, 10**30, 1e308, -1e308, 5e-324])
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=30)
    | st.sampled_from(["", "nan", "NaN", "inf", "-Infinity", "1e999", "0x10", "ü" * 5, "\x00"])
)
JSON = st.recursive(
    SCALARS,
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=10), children, max_size=5),
    max_leaves=20,
)

VALID: dict[str, dict[str, Any]] = {
    "status": {
        "online": True,
        "ts": 1.0,
        "agent_version": "x",
        "capabilities": {"sensors": ["position"], "commands": ["stop"]},
        "sensors": {"position": {"ok": True, "rate_hz": 20.0}},
    },
    "telemetry": {"ts": 1.0, "seq": 1, "data": {"x": 1.0, "y": 2.0, "z": 0.0, "yaw": 0.1}},
    "imu": {"ts": 1.0, "seq": 1, "data": {"accel": [0.0, 0.0, 9.8], "gyro": [0.0, 0.0, 0.0]}},
    "command": {
        "id": "c1",
        "command": "move_forward",
        "args": {"speed": 0.5, "duration_s": 0.2},
        "ts": 1.0,
        "ttl_s": 2.0,
    },
    "ack": {"id": "c1", "status": "done", "reason": "", "ts": 1.0},
    "estop": {"ts": 1.0, "id": "e1", "engaged": True, "reason": "r", "source": "s"},
}


def dump(value: Any) -> bytes:
    """Python's json writes NaN/Infinity tokens and arbitrarily large integers: both are hostile input."""
    return json.dumps(value, allow_nan=True).encode()


@st.composite
def mutated(draw: st.DrawFn, base: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key in draw(st.lists(st.sampled_from(sorted(base)), max_size=3)):
        if draw(st.booleans()):
            out.pop(key, None)
        else:
            out[key] = draw(JSON)
    out.update(draw(st.dictionaries(st.text(max_size=12), JSON, max_size=3)))  # unknown fields
    if "data" in out and isinstance(out["data"], dict) and draw(st.booleans()):
        data = dict(out["data"])
        for key in draw(st.lists(st.sampled_from(sorted(data) or ["x"]), max_size=2)):
            data[key] = draw(JSON)
        out["data"] = data
    return out


def payloads(kind: str) -> st.SearchStrategy[bytes]:
    """Bytes for the ``kind`` of message: mostly near-valid (to reach deep validation), some garbage."""
    base = VALID[kind]
    return st.one_of(
        st.builds(dump, mutated(base)),
        st.builds(dump, JSON),
        st.binary(max_size=200),
        st.builds(lambda b, n: dump(b)[:n], mutated(base), st.integers(0, 200)),  # truncated
        st.just(b""),
    )
