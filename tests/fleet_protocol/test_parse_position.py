"""The shared legacy position parser (agent UDP input and the server's legacy MQTT adapter)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fleet_protocol import ProtocolError, parse_position_text


@pytest.mark.parametrize(
    "value",
    [
        "1.5,-2,0.25",
        "[1.5, -2, 0.25]",
        "1.5 -2 0.25",
        "[1.5 -2 0.25]",
        "(1.5, -2, 0.25)",
        " 1.5 ,\t-2, 0.25\n",
        b"1.5,-2,0.25",
        "[1.5,-2,0.25]",
        '{"x": 1.5, "y": -2, "z": 0.25}',
        [1.5, -2, 0.25],
        (1.5, -2.0, 0.25),
        {"x": 1.5, "y": -2, "z": 0.25},
        "1.5e0,-2e0,2.5e-1",
    ],
)
def test_accepted_shapes(value: object) -> None:
    p = parse_position_text(value)
    assert (p.x, p.y, p.z) == (1.5, -2.0, 0.25)


def test_object_may_carry_yaw_and_omit_z() -> None:
    p = parse_position_text('{"x": 1, "y": 2, "yaw": 0.5}')
    assert (p.x, p.y, p.z, p.yaw) == (1.0, 2.0, 0.0, 0.5)


@pytest.mark.parametrize(
    "value",
    [
        "",
        "1,2",
        "1,2,3,4",
        "a,b,c",
        "nan,1,2",
        "1,inf,2",
        "{bad json",
        '{"y": 1}',
        "[1, 2]",
        [1, 2],
        [True, 1, 2],
        None,
        42,
        b"\xff\xfe",
        "x" * 2000,
        {"x": "one", "y": 2},
        [[1], 2, 3],
    ],
)
def test_refused_shapes(value: object) -> None:
    with pytest.raises(ProtocolError) as exc:
        parse_position_text(value)
    assert exc.value.reason == "bad_position"


@given(st.one_of(st.text(max_size=50), st.binary(max_size=50), st.lists(st.floats(), max_size=4)))
def test_never_raises_anything_but_protocol_error(value: object) -> None:
    try:
        p = parse_position_text(value)
    except ProtocolError:
        return
    assert all(v == v for v in (p.x, p.y, p.z))  # finite numbers only


@given(st.tuples(*[st.floats(allow_nan=False, allow_infinity=False, width=32)] * 3))
def test_round_trips_csv(xyz: tuple[float, float, float]) -> None:
    p = parse_position_text(",".join(repr(v) for v in xyz))
    assert (p.x, p.y, p.z) == pytest.approx(xyz)
