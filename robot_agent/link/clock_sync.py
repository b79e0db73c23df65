"""The sender's clock, read on the robot: an NTP-like exchange with the server over MQTT.

A drive command carries ``ts``, the server's clock when it was made, and must end at ``ts + duration_s`` on
that clock, however late it was delivered. So the agent measures the server's clock against its own
*monotonic* clock (a step of the robot's wall clock changes nothing) on connect and every ``period_s``,
keeps the samples of a recent window and uses the one with the lowest round trip. It reads the server's
clock on the late side of that sample's uncertainty (half its round trip): deadlines err towards stopping.
Until a first sample arrives, the robot's wall clock stands in (offset 0); the command handler then also
caps a drive at ``duration_s`` from its receipt (see docs/safety.md).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

from fleet_protocol import ProtocolError, dumps
from fleet_protocol.clock import TimeRequest, clock_offset, decode_time_response
from robot_agent.util import RejectCounter

log = logging.getLogger(__name__)

SYNC_PERIOD_S = 10.0
#: Requests per sync, a little apart: one of them usually meets a quiet link.
SYNC_BURST = 3
SYNC_BURST_GAP_S = 0.05
#: Samples older than this are forgotten (the estimate itself is kept while no newer one arrives).
WINDOW_S = 60.0
#: A sample whose round trip exceeds this is too uncertain to use (offset error up to half of it).
MAX_RTT_S = 0.5
#: A best round trip above this (the offset is known only to half of it) asks again after RETRY_S rather
#: than the period: a first burst on a busy start (a loaded machine, a Wi-Fi burst) measured 122 ms off on one
#: host and raised a clock alarm for 10 s. At most QUICK_RETRIES times per connection, so a link that is
#: always slow costs no more than the period's traffic afterwards.
GOOD_RTT_S = 0.04
RETRY_S = 1.0
QUICK_RETRIES = 10
#: A larger offset at the first sync is logged as a warning: the robot's NTP is not working.
CLOCK_WARN_MS = 1000.0


@dataclass(frozen=True, slots=True)
class ClockSample:
    at: float  # robot monotonic time of the answer
    offset: float  # server wall clock minus robot monotonic clock, s
    rtt: float  # round trip without the server's own processing time, s


class OffsetEstimator:
    """The lowest-round-trip sample of the last ``window_s`` (the last estimate while the window is empty)."""

    def __init__(self, window_s: float = WINDOW_S, max_rtt_s: float = MAX_RTT_S, max_samples: int = 64) -> None:
        self.window_s = window_s
        self.max_rtt_s = max_rtt_s
        self._samples: collections.deque[ClockSample] = collections.deque(maxlen=max_samples)
        self._best: ClockSample | None = None
        self.refused = 0

    def add(self, t0: float, t1: float, t2: float, t3: float) -> ClockSample | None:
        """One exchange (t0, t3 robot monotonic; t1, t2 server wall clock); None when refused."""
        offset, rtt = clock_offset(t0, t1, t2, t3)
        if not (0.0 <= rtt <= self.max_rtt_s) or t2 < t1 or t3 < t0:
            self.refused += 1
            return None
        sample = ClockSample(t3, offset, rtt)
        self._samples.append(sample)
        self._best = self._pick(t3)
        return sample

    def _pick(self, now: float) -> ClockSample | None:
        while self._samples and now - self._samples[0].at > self.window_s:
            self._samples.popleft()
        if not self._samples:
            return self._best
        return min(self._samples, key=lambda s: s.rtt)

    def best(self, now: float) -> ClockSample | None:
        self._best = self._pick(now)
        return self._best


class ClockSync:
    """Runs on the agent's loop. ``sender_now()`` is what the command handler reads ``ts`` against."""

    def __init__(
        self,
        send_request: Callable[[bytes], None],
        on_first_sync: Callable[[], None] = lambda: None,
        estimator: OffsetEstimator | None = None,
        wall: Callable[[], float] = time.time,
        mono: Callable[[], float] = time.monotonic,
        period_s: float = SYNC_PERIOD_S,
    ) -> None:
        self._send = send_request
        self._on_first_sync = on_first_sync
        self.estimator = estimator or OffsetEstimator()
        self._wall = wall
        self._mono = mono
        self.period_s = period_s
        self._pending: collections.deque[float] = collections.deque(maxlen=4 * SYNC_BURST)
        self._quick_left = QUICK_RETRIES
        self._wake = asyncio.Event()
        self._estimate: ClockSample | None = None
        self.rejects = RejectCounter(log)

    @property
    def synced(self) -> bool:
        return self._estimate is not None

    def sender_now(self) -> float:
        """The server's wall clock now, on the late side of what was measured; the robot's until measured."""
        est = self._estimate
        if est is None:
            return self._wall()
        return self._mono() + est.offset + est.rtt / 2

    def offset_ms(self) -> float | None:
        """The server's wall clock minus the robot's, ms (None until measured): the status' clock_offset_ms."""
        est = self._estimate
        if est is None:
            return None
        return round((est.offset + self._mono() - self._wall()) * 1000, 3)

    def rtt_ms(self) -> float | None:
        est = self._estimate
        return None if est is None else round(est.rtt * 1000, 3)

    def sync_now(self) -> None:
        """Start a sync at once (the link just came up)."""
        self._quick_left = QUICK_RETRIES
        self._wake.set()

    def _retry_soon(self) -> bool:
        """True (a few times per connection) while the best sample is too uncertain to keep for a period."""
        est = self._estimate
        if est is not None and est.rtt > GOOD_RTT_S and self._quick_left > 0:
            self._quick_left -= 1
            return True
        return False

    async def _sleep(self, seconds: float) -> bool:
        """Sleep, or less when ``sync_now`` wakes it (then True)."""
        try:
            await asyncio.wait_for(self._wake.wait(), seconds)
        except TimeoutError:
            return False
        return True

    def on_response(self, payload: bytes, received_mono: float) -> None:
        """``time/resp`` (``received_mono``: when the MQTT thread read it). Never raises."""
        try:
            resp = decode_time_response(payload)
        except ProtocolError as exc:
            self.rejects.reject(exc.reason, exc.detail)
            return
        if resp.t0 not in self._pending:  # not ours, or answered twice (a replica, a retained copy)
            self.rejects.reject("time_unasked", f"t0 {resp.t0}")
            return
        self._pending.remove(resp.t0)
        if self.estimator.add(resp.t0, resp.t1, resp.t2, received_mono) is None:
            self.rejects.reject("time_sample_refused", f"{resp} received at {received_mono}")
            return
        first = self._estimate is None
        self._estimate = self.estimator.best(received_mono)
        if first:
            offset_ms = self.offset_ms() or 0.0
            log.info("clock synced with the server: offset %s ms, round trip %s ms", offset_ms, self.rtt_ms())
            if abs(offset_ms) > CLOCK_WARN_MS:
                log.warning(
                    "this robot's clock is %.1f s off the server's: commands are timed by the measured "
                    "offset, but check NTP (docs/robot-setup.md)",
                    offset_ms / 1000,
                )
            self._on_first_sync()

    def _request(self) -> None:
        t0 = self._mono()
        self._pending.append(t0)
        try:
            self._send(dumps(TimeRequest(t0=t0)))
        except Exception:
            log.exception("clock-sync request failed")

    async def run(self) -> None:
        while True:
            self._wake.clear()  # before the burst: a link that comes up during it asks again at once
            for i in range(SYNC_BURST):
                if i:
                    await asyncio.sleep(SYNC_BURST_GAP_S)
                self._request()
            first = min(self.period_s, RETRY_S)  # the burst's answers are in by then, or refused as too slow
            if not await self._sleep(first) and not self._retry_soon():
                await self._sleep(self.period_s - first)
            if self._estimate is not None:
                self._estimate = self.estimator.best(self._mono())
