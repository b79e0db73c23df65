"""The offset estimator and the drive deadline on the sender's clock (no processes: pure functions and the
command handler on a real event loop with recording motors)."""

from __future__ import annotations

import asyncio
import time
from typing import Any

import orjson
import pytest

from fleet_protocol import Ack, Command, dumps, new_command
from fleet_protocol.clock import TimeResponse, clock_offset
from robot_agent.commands import CommandHandler
from robot_agent.link.clock_sync import ClockSync, OffsetEstimator
from robot_agent.motors.base import MotorDriver
from robot_agent.motors.watchdog import WATCHDOG_MARGIN_S
from tests.support.procs import wait_until


def exchange(
    robot_to_server: float, server_to_robot: float, skew: float, t0: float = 100.0, processing: float = 0.001
) -> tuple[float, float, float, float]:
    """One exchange with one-way delays, the server's clock ``skew`` ahead of the robot's."""
    t1 = t0 + robot_to_server + skew
    t2 = t1 + processing
    t3 = t2 - skew + server_to_robot
    return t0, t1, t2, t3


def test_offset_and_round_trip_of_one_exchange() -> None:
    offset, rtt = clock_offset(*exchange(0.010, 0.010, skew=3.0))
    assert offset == pytest.approx(3.0) and rtt == pytest.approx(0.020)
    # asymmetric delays: the error is half the asymmetry, never more than half the round trip
    offset, rtt = clock_offset(*exchange(0.050, 0.010, skew=3.0))
    assert offset == pytest.approx(3.02) and rtt == pytest.approx(0.060)
    assert abs(offset - 3.0) <= rtt / 2


def test_estimator_keeps_the_lowest_round_trip_of_the_window() -> None:
    est = OffsetEstimator(window_s=60.0, max_rtt_s=0.5)
    est.add(*exchange(0.200, 0.010, skew=-2.0, t0=0.0))  # a congested sample: offset 0.095 s off
    est.add(*exchange(0.002, 0.002, skew=-2.0, t0=1.0))  # the good one
    est.add(*exchange(0.010, 0.100, skew=-2.0, t0=2.0))
    best = est.best(3.0)
    assert best is not None and best.offset == pytest.approx(-2.0) and best.rtt == pytest.approx(0.004)
    # 61 s later the good sample left the window: the best of what is left wins
    est.add(*exchange(0.030, 0.030, skew=-2.0, t0=62.0))
    best = est.best(62.1)
    assert best is not None and best.rtt == pytest.approx(0.060)
    # an empty window keeps the last estimate (the clocks do not drift apart in minutes)
    assert est.best(500.0) == best


def test_estimator_refuses_samples_it_cannot_trust() -> None:
    est = OffsetEstimator(max_rtt_s=0.5)
    assert est.add(*exchange(0.4, 0.4, skew=1.0)) is None  # round trip 0.8 s: error up to 0.4 s
    assert est.add(10.0, 5.0, 4.0, 10.1) is None  # the server sent before it received
    assert est.add(10.0, 5.0, 5.0, 9.0) is None  # answered before asked
    assert est.refused == 3 and est.best(11.0) is None


def test_clock_sync_reads_the_server_clock_on_the_late_side_and_ignores_foreign_answers() -> None:
    async def run() -> None:
        sent: list[bytes] = []
        mono = [1000.0]
        synced: list[bool] = []
        sync = ClockSync(
            sent.append, on_first_sync=lambda: synced.append(True), wall=lambda: 5000.0, mono=lambda: mono[0]
        )
        assert not sync.synced and sync.sender_now() == 5000.0  # unsynced: the robot's own clock
        sync._request()
        assert len(sent) == 1
        t0 = 1000.0
        # a stranger's answer (t0 never sent) and garbage change nothing
        sync.on_response(dumps(TimeResponse(t0=999.0, t1=7000.0, t2=7000.0)), 1000.02)
        sync.on_response(b"not json", 1000.02)
        assert not sync.synced and sync.rejects.counts == {"time_unasked": 1, "bad_json": 1}
        # server clock = monotonic + 6000; 10 ms each way
        sync.on_response(dumps(TimeResponse(t0=t0, t1=t0 + 6000.010, t2=t0 + 6000.011)), t0 + 0.021)
        assert sync.synced and synced == [True]
        mono[0] = 1010.0
        assert sync.sender_now() == pytest.approx(1010.0 + 6000.0 + 0.010)  # + half the 20 ms round trip
        assert sync.offset_ms() == pytest.approx((7010.0 - 5000.0) * 1000)  # server minus robot wall clock
        assert sync.rtt_ms() == pytest.approx(20.0)
        # the same answer again (a duplicate) is not a second sample
        sync.on_response(dumps(TimeResponse(t0=t0, t1=t0 + 6000.010, t2=t0 + 6000.011)), t0 + 0.5)
        assert sync.rtt_ms() == pytest.approx(20.0)

    asyncio.run(run())


def test_clock_sync_asks_in_bursts_periodically_and_at_once_when_the_link_comes_up() -> None:
    async def run() -> None:
        sent: list[float] = []
        sync = ClockSync(lambda payload: sent.append(orjson.loads(payload)["t0"]), period_s=2.0)
        task = asyncio.create_task(sync.run())
        try:
            await wait_until(lambda: len(sent) == 3, 2)  # the first burst, at start
            assert sent == sorted(sent) and sent[2] - sent[0] >= 0.09  # 3 requests, 50 ms apart
            sync.sync_now()  # the link came up: no waiting for the period
            await wait_until(lambda: len(sent) == 6, 1.0)  # well before the 2 s period
            await wait_until(lambda: len(sent) == 9, 3.0)  # and then every period_s
            assert sent[6] - sent[5] >= 1.9
        finally:
            task.cancel()

    asyncio.run(run())


def test_an_uncertain_first_sync_is_measured_again_within_a_second_not_a_period() -> None:
    """A burst answered only slowly (a busy start: the offset is known to 150 ms) is asked again after RETRY_S;
    once a quick answer arrives, the period applies. A period of 4 s tells the two apart."""

    async def run() -> None:
        sent: list[float] = []
        sync = ClockSync(lambda payload: sent.append(orjson.loads(payload)["t0"]), period_s=4.0)

        def answer(t0: float, rtt: float) -> None:  # the server's clock = the robot's monotonic clock + 50 s
            sync.on_response(dumps(TimeResponse(t0=t0, t1=t0 + rtt / 2 + 50, t2=t0 + rtt / 2 + 50)), t0 + rtt)

        task = asyncio.create_task(sync.run())
        try:
            await wait_until(lambda: len(sent) == 3, 2)
            for t0 in sent:
                answer(t0, 0.3)
            assert sync.rtt_ms() == pytest.approx(300.0)
            await wait_until(lambda: len(sent) == 6, 2.5)  # RETRY_S later, not 4 s
            assert sent[3] - sent[2] < 1.5
            for t0 in sent[3:]:
                answer(t0, 0.004)
            assert sync.rtt_ms() == pytest.approx(4.0)
            await asyncio.sleep(2.5)
            assert len(sent) == 6  # certain now: the next burst waits for the period
            await wait_until(lambda: len(sent) == 9, 3.0)
            assert sent[6] - sent[5] >= 3.9
        finally:
            task.cancel()

    asyncio.run(run())


class Motors(MotorDriver):
    def __init__(self) -> None:
        self.calls: list[tuple[str, float]] = []

    @classmethod
    def create(cls, config: Any, world: Any) -> Motors:
        return cls()

    # the loop's clock is time.monotonic(); stop() may also come from the motor watchdog's thread
    def set(self, left: float, right: float) -> None:
        self.calls.append(("set", time.monotonic()))

    def stop(self) -> None:
        self.calls.append(("stop", time.monotonic()))

    def operable(self) -> tuple[bool, str]:
        return True, ""


def _drive(h: CommandHandler, ts: float, duration: float) -> Command:
    cmd = Command.model_validate(
        {**new_command("move_forward", {"speed": 1.0, "duration_s": duration}).model_dump(), "ts": ts}
    )
    h.handle_payload(dumps(cmd))
    return cmd


@pytest.mark.parametrize("offset", [0.0, 7.5, -7.5])
def test_a_delayed_drive_ends_at_its_ts_plus_duration_on_the_senders_clock(offset: float) -> None:
    """The robot's loop clock plus ``offset`` is the sender's clock (what ClockSync provides)."""

    async def run() -> None:
        loop = asyncio.get_running_loop()
        motors = Motors()
        acks: list[Ack] = []
        h = CommandHandler(motors, acks.append, clock=lambda: loop.time() + offset)
        try:
            start = loop.time()
            # delivered 0.8 s late with 0.5 s to run: it ended before it arrived
            late = _drive(h, start + offset - 0.8, 0.5)
            assert [(a.id, a.status) for a in acks] == [(late.id, "expired")] and motors.calls == []
            assert "before it arrived" in acks[0].reason
            # delivered 0.3 s late with 0.5 s to run: on for 0.2 s, not 0.5 s
            ok = _drive(h, start + offset - 0.3, 0.5)
            await wait_until(lambda: len(acks) == 3, 2)
            (on, _), (off, t_off), *_ = motors.calls
            assert (on, off) == ("set", "stop") and [a.status for a in acks if a.id == ok.id] == ["accepted", "done"]
            assert 0.2 <= t_off - start <= 0.2 + WATCHDOG_MARGIN_S  # the deadline, plus at most the timer latency
            # a sender clock running ahead never stretches a drive beyond duration_s from its receipt
            motors.calls.clear()
            t = loop.time()
            _drive(h, t + offset + 3.0, 0.2)
            await wait_until(lambda: len(acks) == 5, 2)
            (on, _), (off, t_off), *_ = motors.calls
            assert (on, off) == ("set", "stop") and 0.2 <= t_off - t <= 0.2 + WATCHDOG_MARGIN_S
        finally:
            motors.shutdown()

    asyncio.run(run())
