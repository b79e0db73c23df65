"""Answers the server's gap repair requests from the replay ring (``robot_agent/telemetry/replay.py``).

A request names a boot, a stream and ``seq`` ranges. The answer is one or more replies of at most
``REPLY_TARGET_BYTES`` with the kept messages exactly as first published, and the ranges that are no
longer kept (the server then records them as lost). A request that does not parse is counted and logged
(rate-limited) and changes nothing. Runs on the agent's asyncio loop.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from fleet_protocol import MAX_JSON_PAYLOAD_BYTES, ProtocolError
from fleet_protocol.repair import (
    MAX_REPAIR_RANGES,
    REPLY_TARGET_BYTES,
    SeqRange,
    decode_repair_request,
    encode_repair_reply,
)
from robot_agent.telemetry.replay import ReplayRing

log = logging.getLogger(__name__)

#: room for the reply's own fields around the messages
_REPLY_HEAD_BYTES = 1024


class RepairResponder:
    def __init__(self, *, ring: ReplayRing, publish: Callable[[bytes], None]) -> None:
        self._ring = ring
        self._publish = publish
        self.requests = 0
        self.rejected = 0
        self.replayed = 0
        self.unavailable = 0
        self._last_warning = 0.0

    def handle_payload(self, payload: bytes) -> None:
        try:
            req = decode_repair_request(payload)
        except ProtocolError as exc:
            self.rejected += 1
            if time.monotonic() - self._last_warning > 10.0:
                self._last_warning = time.monotonic()
                log.warning("repair request refused (%d so far): %s", self.rejected, exc)
            return
        self.requests += 1
        found, missing = self._ring.lookup(req.boot, req.stream, list(req.ranges))
        chunks: list[list[bytes]] = [[]]
        size = 0
        for seq, envelope in found:
            if len(envelope) + _REPLY_HEAD_BYTES > MAX_JSON_PAYLOAD_BYTES:
                missing.append((seq, seq))  # cannot travel in a reply: the server records it as lost
                continue
            if chunks[-1] and size + len(envelope) > REPLY_TARGET_BYTES:
                chunks.append([])
                size = 0
            chunks[-1].append(envelope)
            size += len(envelope) + 1
        unavailable = _merge(missing)
        groups = [unavailable[i : i + MAX_REPAIR_RANGES] for i in range(0, len(unavailable), MAX_REPAIR_RANGES)]
        replies: list[tuple[list[bytes], list[SeqRange]]] = [(chunk, []) for chunk in chunks]
        if groups:
            replies[-1] = (chunks[-1], groups[0])
            replies += [([], g) for g in groups[1:]]
        for i, (chunk, gone) in enumerate(replies):
            self._publish(encode_repair_reply(req.id, req.boot, req.stream, chunk, gone, i == len(replies) - 1))
            self.replayed += len(chunk)
        self.unavailable += sum(hi - lo + 1 for lo, hi in unavailable)
        if unavailable:
            log.info("repair %s/%s: %d replayed, no longer kept: %s", req.stream, req.boot, len(found), unavailable[:5])


def _merge(ranges: list[SeqRange]) -> list[SeqRange]:
    out: list[SeqRange] = []
    for lo, hi in sorted(ranges):
        if out and lo <= out[-1][1] + 1:
            out[-1] = (out[-1][0], max(hi, out[-1][1]))
        else:
            out.append((lo, hi))
    return out
