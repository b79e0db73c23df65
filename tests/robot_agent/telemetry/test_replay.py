"""The agent's replay ring and its answers to repair requests (robot_agent/telemetry/replay.py and
repair.py): bounded by age and size, kept byte for byte, on disk across a restart, and a request answered in
replies the server accepts, with the ranges no longer kept."""

from __future__ import annotations

from pathlib import Path

import orjson

from fleet_protocol import MAX_JSON_PAYLOAD_BYTES, encode_telemetry
from fleet_protocol.repair import (
    MAX_REPAIR_SEQS,
    decode_repair_reply,
    encode_repair_request,
    new_repair_request,
    replayed_messages,
)
from robot_agent.telemetry.repair import RepairResponder
from robot_agent.telemetry.replay import ENTRY_OVERHEAD, ReplayDisk, ReplayRing


class Clock:
    def __init__(self) -> None:
        self.t = 1_000_000.0

    def __call__(self) -> float:
        return self.t


def _payload(seq: int, boot: str = "b1", pad: int = 0) -> bytes:
    return encode_telemetry(
        seq, {"x": 1.0, "y": 1.0, "z": 0.0, "yaw": None, "pad": "p" * pad}, ts=1_000_000.0 + seq, boot=boot
    )


def test_ring_keeps_messages_byte_for_byte_and_names_what_it_lacks() -> None:
    ring = ReplayRing("b1", clock=Clock())
    sent = {seq: _payload(seq) for seq in range(100)}
    for seq, p in sent.items():
        ring.add("position", seq, p)
    found, missing = ring.lookup("b1", "position", [(90, 120), (10, 12)])
    assert [s for s, _ in found] == [10, 11, 12, *range(90, 100)]
    assert all(p == sent[s] for s, p in found)
    assert missing == [(100, 120)]
    assert ring.lookup("b1", "imu", [(0, 3)]) == ([], [(0, 3)])  # a stream it never had
    assert ring.lookup("other-boot", "position", [(0, 3)]) == ([], [(0, 3)])


def test_ring_drops_the_oldest_message_by_age_and_by_total_size() -> None:
    clock = Clock()
    ring = ReplayRing("b1", window_s=10.0, max_bytes=1_000_000, clock=clock)
    for seq in range(20):
        ring.add("imu", seq, _payload(seq))
        clock.t += 1.0
    ring.maintain()
    found, missing = ring.lookup("b1", "imu", [(0, 19)])
    assert missing == [(0, 9)] and [s for s, _ in found] == list(range(10, 20))  # older than 10 s: gone

    size = len(_payload(199, pad=1000)) + ENTRY_OVERHEAD  # (every seq of 100..199 has this size)
    ring = ReplayRing("b1", window_s=600.0, max_bytes=50 * size, clock=Clock())
    for seq in range(200):  # two streams share the budget; the oldest message anywhere goes first
        ring.add("a" if seq % 2 else "b", seq, _payload(seq, pad=1000))
    assert ring.bytes <= 50 * size and ring.stats()["messages"] == 50
    kept = sorted(s for stream in ("a", "b") for s, _ in ring.lookup("b1", stream, [(0, 199)])[0])
    assert kept == list(range(150, 200))


def test_ring_on_disk_survives_a_restart_and_a_torn_last_record(tmp_path: Path) -> None:
    clock = Clock()
    first = ReplayRing("boot-a", disk=ReplayDisk(tmp_path, "boot-a"), clock=clock)
    sent = {seq: _payload(seq, "boot-a") for seq in range(300)}
    for seq, p in sent.items():
        first.add("position", seq, p)
    first.close()
    segment = next(tmp_path.glob("boot-a.*.ring"))
    with open(segment, "ab") as f:
        f.write(b"\x08\x00\x00")  # the agent died in the middle of a record

    clock.t += 60
    second = ReplayRing("boot-b", disk=ReplayDisk(tmp_path, "boot-b"), clock=clock)
    found, missing = second.lookup("boot-a", "position", [(0, 299)])
    assert missing == [] and all(p == sent[s] for s, p in found) and len(found) == 300
    second.add("position", 0, _payload(0, "boot-b"))  # the new run counts from 0 again, kept apart
    assert [s for s, _ in second.lookup("boot-b", "position", [(0, 5)])[0]] == [0]
    second.close()

    clock.t += 601  # a third start, after the window: the first run's messages are no longer offered
    third = ReplayRing("boot-c", disk=ReplayDisk(tmp_path, "boot-c"), clock=clock)
    assert third.lookup("boot-a", "position", [(0, 299)]) == ([], [(0, 299)])
    third.maintain()
    assert not list(tmp_path.glob("boot-a.*.ring"))  # and its files are deleted
    third.close()


def test_a_large_request_is_answered_in_replies_the_server_accepts() -> None:
    ring = ReplayRing("b1", clock=Clock())
    sent = {seq: _payload(seq, pad=200) for seq in range(MAX_REPAIR_SEQS + 10)}
    for seq, p in sent.items():
        ring.add("position", seq, p)
    replies: list[bytes] = []
    responder = RepairResponder(ring=ring, publish=replies.append)
    n = MAX_REPAIR_SEQS
    req = new_repair_request("b1", "position", [(5, n - 6), (n + 5, n + 14)])  # n seq numbers, the most allowed
    responder.handle_payload(encode_repair_request(req))
    assert len(replies) > 1
    assert all(len(r) <= MAX_JSON_PAYLOAD_BYTES for r in replies)
    decoded = [decode_repair_reply(r) for r in replies]
    assert [d.final for d in decoded] == [False] * (len(decoded) - 1) + [True]
    assert all(d.id == req.id and d.boot == "b1" and d.stream == "position" for d in decoded)
    got = [m for d in decoded for m in replayed_messages(d)[0]]
    assert [m.seq for m in got] == [*range(5, MAX_REPAIR_SEQS - 5), *range(MAX_REPAIR_SEQS + 5, MAX_REPAIR_SEQS + 10)]
    raw = [orjson.dumps(m) for d in decoded for m in d.messages]
    assert all(orjson.loads(r) == orjson.loads(sent[m.seq]) for r, m in zip(raw, got, strict=True))
    assert decoded[-1].unavailable == [(MAX_REPAIR_SEQS + 10, MAX_REPAIR_SEQS + 14)]


def test_bad_requests_are_counted_and_answer_nothing() -> None:
    ring = ReplayRing("b1", clock=Clock())
    ring.add("position", 0, _payload(0))
    replies: list[bytes] = []
    responder = RepairResponder(ring=ring, publish=replies.append)
    for bad in (
        b"",
        b"not json",
        b"[]",
        b'{"id": "x", "ts": 1, "boot": "b1", "stream": "position"}',
        b'{"id": "x", "ts": 1, "boot": "b1", "stream": "position", "ranges": [[true, 3]]}',
        b'{"id": "x", "ts": 1, "boot": "b1", "stream": "position", "ranges": [[5, 3]]}',
        b'{"id": "x", "ts": 1, "boot": "b/1", "stream": "position", "ranges": [[0, 3]]}',
        orjson.dumps({"id": "x", "ts": 1, "boot": "b1", "stream": "position", "ranges": [[0, MAX_REPAIR_SEQS]]}),
    ):
        responder.handle_payload(bad)
    assert responder.rejected == 8 and replies == []
    responder.handle_payload(encode_repair_request(new_repair_request("b1", "position", [(0, 0)])))
    assert len(replies) == 1 and responder.requests == 1


def test_the_size_cap_counts_what_the_ring_really_holds_in_memory() -> None:
    """The 50 MB cap is only a cap if the counted size is the memory held: payloads straight from orjson
    keep a 4 KiB allocation each, so the ring must keep exact-size copies (measured with tracemalloc)."""
    import tracemalloc

    payloads = [_payload(seq) for seq in range(20_000)]  # made first: only what the ring keeps is measured
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        ring = ReplayRing("b1", clock=Clock())
        for seq, p in enumerate(payloads):
            ring.add("position", seq, p)
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert ring.stats()["messages"] == 20_000
    assert 0.8 * ring.bytes <= held <= 1.2 * ring.bytes, (held, ring.bytes)
