"""LiveHub queueing: a slow client loses old telemetry per (robot, stream), never control messages."""

from __future__ import annotations

import asyncio

import orjson

from backend.services.live.hub import LiveHub
from tests.support.procs import wait_until


def test_slow_client_coalesces_per_stream_and_counts_drops():
    async def run() -> tuple[list[list[dict]], int, dict]:
        frames: list[list[dict]] = []
        gate = asyncio.Event()

        async def slow_send(frame: str) -> None:
            frames.append(orjson.loads(frame))
            await gate.wait()  # the first send blocks: the client is "slow"

        hub = LiveHub(queue_max=10, flush_interval_s=0.001)
        client = hub.add(slow_send)
        client.subscribe(["*"], ["*"])
        task = asyncio.create_task(client.run())
        hub.publish_control({"type": "robot", "robot": {"id": "a"}}, "a")
        await wait_until(lambda: len(frames) == 1)  # the sender took the first frame and blocks in send
        for i in range(100):
            hub.publish_telemetry("a", "position", float(i), i, {"x": i})
            if i % 10 == 0:
                hub.publish_telemetry("b", "imu", float(i), i, {"g": i})
        hub.publish_control({"type": "estop", "estop": {"engaged": True}})
        # ingest never blocked although the client did not read anything
        dropped = client.dropped
        gate.set()
        await wait_until(lambda: len(frames) >= 2)
        task.cancel()
        return frames, dropped, hub.stats()

    frames, dropped, stats = asyncio.run(run())
    assert frames[0] == [{"type": "robot", "robot": {"id": "a"}}]
    second = frames[1]
    tel = [m for m in second if m["type"] == "telemetry"]
    assert len(tel) == 10
    # the busy stream lost its oldest messages; the newest survive in order
    a = [m["seq"] for m in tel if m["robot_id"] == "a"]
    assert a == sorted(a) and a[-1] == 99
    assert any(m["robot_id"] == "b" for m in tel)  # the quiet stream was not starved by the busy one
    assert second[-1] == {"type": "estop", "estop": {"engaged": True}}
    assert dropped == 100 + 10 - 10 == stats["dropped"]


def test_filters_and_unsubscribed_clients():
    async def run() -> list[list[dict]]:
        frames: list[list[dict]] = []

        async def send(frame: str) -> None:
            frames.append(orjson.loads(frame))

        hub = LiveHub(queue_max=100, flush_interval_s=0.001)
        idle = hub.add(send)  # never subscribed: gets nothing
        c = hub.add(send)
        c.subscribe(["r1"], ["position"])
        tasks = [asyncio.create_task(idle.run()), asyncio.create_task(c.run())]
        hub.publish_telemetry("r1", "position", 1.0, 1, {})
        hub.publish_telemetry("r1", "imu", 1.0, 1, {})
        hub.publish_telemetry("r2", "position", 1.0, 1, {})
        hub.publish_control({"type": "command", "command": {"robot_id": "r2"}}, "r2")
        hub.publish_control({"type": "estop", "estop": {}})
        # the e-stop, published last, reached the subscribed client: what came before it was sent first
        await wait_until(lambda: any(m["type"] == "estop" for f in frames for m in f))
        for t in tasks:
            t.cancel()
        return frames

    frames = asyncio.run(run())
    msgs = [m for f in frames for m in f]
    assert [(m["type"], m.get("robot_id"), m.get("stream")) for m in msgs] == [
        ("telemetry", "r1", "position"),
        ("estop", None, None),
    ]


def test_frames_carry_each_message_once_in_arrival_order_across_rounds_and_overflow():
    """Each frame holds exactly what was queued since the last one (keys recur across rounds); a queue
    emptied by an overflow drop and refilled is sent once, in arrival order with the others."""

    async def run() -> tuple[list[list[dict]], list[list[dict]]]:
        frames: list[list[dict]] = []

        async def send(frame: str) -> None:
            frames.append(orjson.loads(frame))

        hub = LiveHub(queue_max=100, flush_interval_s=0.001)
        client = hub.add(send)
        client.subscribe(["*"], ["position"])
        task = asyncio.create_task(client.run())
        for rnd in range(3):
            for rid in ("c", "a", "b", "a"):
                hub.publish_telemetry(rid, "position", float(rnd), rnd, {"r": rid})
            await wait_until(lambda rnd=rnd: len(frames) == rnd + 1)  # the sender took this round as one frame
        task.cancel()

        slow_frames: list[list[dict]] = []
        gate = asyncio.Event()

        async def slow_send(frame: str) -> None:
            slow_frames.append(orjson.loads(frame))
            await gate.wait()

        slow_hub = LiveHub(queue_max=3, flush_interval_s=0.001)
        slow = slow_hub.add(slow_send)
        slow.subscribe(["*"], ["position"])
        slow_task = asyncio.create_task(slow.run())
        slow_hub.publish_control({"type": "robot", "robot": {"id": "x"}})
        await wait_until(lambda: len(slow_frames) == 1)  # blocked in its first send
        for seq, rid in enumerate(("a", "b", "c", "d", "a")):
            # d overflows: the oldest of a busiest queue (a's only message) goes; a's queue then refills
            slow_hub.publish_telemetry(rid, "position", float(seq), seq, {})
        gate.set()
        await wait_until(lambda: len(slow_frames) >= 2)
        slow_task.cancel()
        return frames, slow_frames

    frames, slow_frames = asyncio.run(run())
    assert [[(m["robot_id"], m["seq"]) for m in f] for f in frames] == [
        [("c", rnd), ("a", rnd), ("b", rnd), ("a", rnd)] for rnd in range(3)
    ]
    second = [(m["robot_id"], m["seq"]) for m in slow_frames[1]]
    assert second == [("c", 2), ("d", 3), ("a", 4)]  # a:0 and b:1 dropped (queue of 3), nothing twice
