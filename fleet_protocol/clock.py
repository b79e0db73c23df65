"""Clock sync over MQTT, NTP-style: payloads of ``{prefix}/{robot}/time/req`` and ``.../time/resp``.

A drive ends at its ``ts + duration_s`` on the *sender's* clock, so a robot must read that clock: it asks
the server's time, ``t0`` being its own send time (on any clock of its own, opaque to the server, which
echoes it), and gets back ``t1`` (server receive) and ``t2`` (server send), both server wall-clock epoch
seconds. With ``t3`` the robot's receive time (on the clock of ``t0``):

* offset (server minus robot) = ((t1 - t0) + (t2 - t3)) / 2
* round trip = (t3 - t0) - (t2 - t1); the offset is exact to within half of it.
"""

from __future__ import annotations

from pydantic import field_validator

from fleet_protocol.codec import _load_json, _validate
from fleet_protocol.core import _finite, _Wire


class TimeRequest(_Wire):
    t0: float

    _t0 = field_validator("t0")(_finite)


class TimeResponse(_Wire):
    t0: float
    t1: float
    t2: float

    _t = field_validator("t0", "t1", "t2")(_finite)


def decode_time_request(payload: bytes) -> TimeRequest:
    return _validate(TimeRequest, _load_json(payload), "bad_time_request")


def decode_time_response(payload: bytes) -> TimeResponse:
    return _validate(TimeResponse, _load_json(payload), "bad_time_response")


def clock_offset(t0: float, t1: float, t2: float, t3: float) -> tuple[float, float]:
    """(offset, round trip) of one exchange; see the module docstring."""
    return ((t1 - t0) + (t2 - t3)) / 2.0, (t3 - t0) - (t2 - t1)
