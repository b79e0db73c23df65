"""Legacy UDP inputs: the seed's datagram formats over real loopback sockets."""

from __future__ import annotations

import asyncio
import socket
from typing import Any

import pytest

from fleet_protocol import ImuData, ProtocolError
from robot_agent.config import LegacyUdpConfig
from robot_agent.legacy.udp import LegacyUdpHub, parse_apriltag, parse_imu, parse_position


def test_imu_formats() -> None:
    expected = {"accel": [0.1, -0.2, 9.8], "gyro": [0.0, 0.01, -0.5]}
    for text in (
        b"0.1,-0.2,9.8,0.0,0.01,-0.5",
        b"0.1 -0.2 9.8 0.0 0.01 -0.5\n",
        b"[0.1,-0.2,9.8,0,0.01,-0.5]",
        b'{"accel": [0.1,-0.2,9.8], "gyro": [0,0.01,-0.5]}',
    ):
        assert parse_imu(text) == expected
        ImuData.model_validate(parse_imu(text))


@pytest.mark.parametrize(
    "bad",
    [
        b"",
        b"1,2,3",
        b"1,2,3,4,5,6,7",
        b"a,b,c,d,e,f",
        b"nan,0,0,0,0,0",
        b"\xff",
        b'{"accel": [1]}',
        b"[true,1,2,3,4,5]",
        b"x" * 20000,
    ],
)
def test_imu_refused(bad: bytes) -> None:
    with pytest.raises(ProtocolError):
        parse_imu(bad)


def test_position_and_apriltag() -> None:
    assert parse_position(b"[1.0, 2.0, 0.5]") == {"x": 1.0, "y": 2.0, "z": 0.5}
    assert parse_position(b"1 2 3") == {"x": 1.0, "y": 2.0, "z": 3.0}
    assert parse_apriltag(b'{"id": 3, "pose": [[1,0,0]]}') == {"raw": {"id": 3, "pose": [[1, 0, 0]]}}
    with pytest.raises(ProtocolError):
        parse_apriltag(b"{not json")
    with pytest.raises(ProtocolError):
        parse_position(b"1;2")


def test_hub_over_real_sockets_counts_bad_datagrams_and_keeps_listening() -> None:
    async def body() -> None:
        hub = LegacyUdpHub(LegacyUdpConfig(bind="127.0.0.1", imu_port=0, position_port=0, apriltag_port=0))
        try:
            qpos = await hub.subscribe("position")
            qimu = await hub.subscribe("imu")
            qtag = await hub.subscribe("apriltag")
            ports = {k: hub.bound_port(k) for k in ("position", "imu", "apriltag")}
            assert all(ports.values())
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(b"garbage", ("127.0.0.1", ports["position"]))
                s.sendto(b"1,2,3", ("127.0.0.1", ports["position"]))
                s.sendto(b"1,2,3,4,5,6", ("127.0.0.1", ports["imu"]))
                s.sendto(b"\x00\x01", ("127.0.0.1", ports["imu"]))
                s.sendto(b'[{"tag": 1}]', ("127.0.0.1", ports["apriltag"]))
            pos = await asyncio.wait_for(qpos.get(), 2)
            imu = await asyncio.wait_for(qimu.get(), 2)
            tag = await asyncio.wait_for(qtag.get(), 2)
            assert pos == {"x": 1.0, "y": 2.0, "z": 3.0}
            assert imu == {"accel": [1.0, 2.0, 3.0], "gyro": [4.0, 5.0, 6.0]}
            assert tag == {"raw": [{"tag": 1}]}
            assert hub.rejects.counts["bad_position"] == 1 and hub.rejects.counts["bad_imu"] == 1
            assert hub.received == {"position": 1, "imu": 1, "apriltag": 1}
        finally:
            hub.close()

    asyncio.run(body())


def test_hub_queue_is_bounded_drop_oldest() -> None:
    async def body() -> None:
        hub = LegacyUdpHub(LegacyUdpConfig(position_port=0))
        try:
            q: asyncio.Queue[dict[str, Any]] = await hub.subscribe("position")
            for i in range(hub.QUEUE_SIZE + 25):
                hub.feed("position", f"{i},0,0".encode())
            assert q.qsize() == hub.QUEUE_SIZE
            assert hub.dropped["position"] == 25
            assert (await q.get())["x"] == 25.0
        finally:
            hub.close()

    asyncio.run(body())


def test_port_in_use_raises_for_the_supervisor_to_report() -> None:
    async def body() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
            taken.bind(("127.0.0.1", 0))
            hub = LegacyUdpHub(LegacyUdpConfig(imu_port=taken.getsockname()[1]))
            try:
                with pytest.raises(OSError):
                    await hub.subscribe("imu")
            finally:
                hub.close()

    asyncio.run(body())
