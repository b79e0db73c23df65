"""Gap repair: the server asks a robot for telemetry the broker dropped, the robot replays it.

A robot keeps its recent telemetry in a replay ring (``robot_agent/telemetry/replay.py``). When the server
sees a ``seq`` gap in a stream it publishes a :class:`RepairRequest` on ``{prefix}/{id}/repair/request``; the
robot answers on ``{prefix}/{id}/repair/reply`` with one or more :class:`RepairReply` messages: the
original telemetry envelopes, byte for byte (so ``ts`` is the original one), and the ranges it no longer
has. The last reply of a request has ``final: true``. Topics: :class:`fleet_protocol.Topics`; for
people: ``docs/protocol.md``.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable
from typing import Annotated, Any

import orjson
from pydantic import Field, field_validator

from fleet_protocol.codec import STREAM_SCHEMAS, _load_json, _validate
from fleet_protocol.core import STREAM_PATTERN, ProtocolError, _finite, _Wire, now
from fleet_protocol.payloads import BOOT_ID_PATTERN, Telemetry

#: ranges per request, and seq numbers per request (a robot answers in replies of at most
#: REPLY_TARGET_BYTES, so one request costs it a bounded amount of work)
MAX_REPAIR_RANGES = 64
MAX_REPAIR_SEQS = 5000
#: a robot packs replayed messages into replies of about this size (well under MAX_JSON_PAYLOAD_BYTES)
REPLY_TARGET_BYTES = 192 * 1024

SeqRange = tuple[int, int]
#: a seq number on the wire: a JSON integer (never `true` or 1.0), like Telemetry.seq
WireSeq = Annotated[int, Field(strict=True, ge=0, lt=2**63)]


def _check_ranges(ranges: list[SeqRange]) -> list[SeqRange]:
    total = 0
    for lo, hi in ranges:
        if lo < 0 or hi < lo or hi >= 2**63:
            raise ValueError(f"bad range [{lo}, {hi}]")
        total += hi - lo + 1
    if total > MAX_REPAIR_SEQS:
        raise ValueError(f"{total} seq numbers asked, at most {MAX_REPAIR_SEQS}")
    return ranges


class RepairRequest(_Wire):
    """``{prefix}/{id}/repair/request`` (server -> robot): send these inclusive ``seq`` ranges again."""

    id: str = Field(min_length=1, max_length=64)
    ts: float
    boot: str = Field(pattern=BOOT_ID_PATTERN)
    stream: str = Field(pattern=STREAM_PATTERN)
    ranges: list[tuple[WireSeq, WireSeq]] = Field(min_length=1, max_length=MAX_REPAIR_RANGES)

    _r = field_validator("ranges")(_check_ranges)
    _ts = field_validator("ts")(_finite)


class RepairReply(_Wire):
    """``{prefix}/{id}/repair/reply`` (robot -> server). ``messages`` are raw telemetry envelopes (checked
    one by one by :func:`replayed_messages`); ``unavailable``: asked-for ranges the robot no longer has."""

    id: str = Field(min_length=1, max_length=64)
    boot: str = Field(pattern=BOOT_ID_PATTERN)
    stream: str = Field(pattern=STREAM_PATTERN)
    messages: list[Any] = Field(default_factory=list)
    unavailable: list[tuple[WireSeq, WireSeq]] = Field(default_factory=list, max_length=MAX_REPAIR_RANGES)
    final: bool = True

    _u = field_validator("unavailable")(_check_ranges)


def new_repair_request(boot: str, stream: str, ranges: list[SeqRange]) -> RepairRequest:
    return RepairRequest(id=uuid.uuid4().hex[:16], ts=now(), boot=boot, stream=stream, ranges=ranges)


def encode_repair_request(req: RepairRequest) -> bytes:
    return orjson.dumps(req.model_dump(mode="json"))


def decode_repair_request(payload: bytes) -> RepairRequest:
    return _validate(RepairRequest, _load_json(payload), "bad_repair_request")


def decode_repair_reply(payload: bytes) -> RepairReply:
    return _validate(RepairReply, _load_json(payload), "bad_repair_reply")


def encode_repair_reply(
    request_id: str, boot: str, stream: str, envelopes: list[bytes], unavailable: list[SeqRange], final: bool
) -> bytes:
    """The reply with ``envelopes`` (telemetry payloads exactly as first published) spliced in unparsed."""
    head = orjson.dumps({"id": request_id, "boot": boot, "stream": stream, "unavailable": unavailable, "final": final})
    return head[:-1] + b',"messages":[' + b",".join(envelopes) + b"]}"


def replayed_messages(reply: RepairReply, wanted: Callable[[int], bool] | None = None) -> tuple[list[Telemetry], int]:
    """The reply's valid messages of its boot (each checked like live telemetry) and how many were refused.
    ``wanted(seq)`` skips, before the (costlier) validation, messages the receiver has no use for."""
    good: list[Telemetry] = []
    refused = 0
    schema = STREAM_SCHEMAS.get(reply.stream)
    for raw in reply.messages:
        if wanted is not None and isinstance(raw, dict):
            seq = raw.get("seq")
            if type(seq) is int and not wanted(seq):
                continue
        try:
            msg = _validate(Telemetry, raw, "bad_telemetry")
            if msg.boot != reply.boot:
                raise ProtocolError("bad_telemetry", "boot differs from the reply's")
            if schema is not None:
                msg.data = _validate(schema, msg.data, f"bad_{reply.stream}").model_dump(mode="json")
        except ProtocolError:
            refused += 1
            continue
        good.append(msg)
    return good, refused
