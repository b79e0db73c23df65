"""Gap repair: asks robots for the telemetry the broker dropped and stores what comes back exactly once.

The broker drops QoS 1 messages for a subscriber that falls behind (Mosquitto's ``max_queued_messages``)
without telling anyone. Every live telemetry message passes :meth:`GapRepair.observe`, which opens a gap
when a stream's ``seq`` jumps (per boot id: ``seq`` restarts at 0 with the agent). After ``grace_s`` (a
late original may still come) :meth:`GapRepair.tick` asks the robot for the open ranges on
``{prefix}/{id}/repair/request``; :meth:`GapRepair.on_reply` stores every replayed message and closes the
open seqs among them. The telemetry table's unique key (robot, stream, seq, ts) stores each once (a reply
answered twice, an original that arrived before or after its repair: a replay carries the original bytes and
so the original ``ts``), and a reply the broker delivers again because its rows could not be kept (the
writer withheld its ack, store/writer.py) is stored then, although its seqs were closed. A range is recorded
as lost when the robot answers that it no longer has it, after ``max_unanswered`` requests in a row got no
reply, or when it is older than the robot's replay window. Everything runs on the event loop.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

from backend.comms.base import Publisher
from backend.core.logging import RateLimitedLogger
from backend.core.rejects import InboundRejects
from backend.schemas import GapRange, StreamStats
from backend.services.fleet.registry import Registry
from backend.services.telemetry.gaps import BootGaps, InFlight, StreamGaps, runs
from backend.services.telemetry.ingest import TelemetryIngest
from fleet_protocol import QOS_REPAIR, Topics
from fleet_protocol.repair import (
    MAX_REPAIR_RANGES,
    MAX_REPAIR_SEQS,
    decode_repair_reply,
    encode_repair_request,
    new_repair_request,
    replayed_messages,
)

log = logging.getLogger(__name__)

#: ranges listed in one ``telemetry_gap`` event (the count covers all of them)
EVENT_RANGES = 20


@dataclass
class GapSummary:
    """What the stream summary shows for one stream (counts are messages, ranges inclusive)."""

    boot: str | None
    detected: int
    open: int
    repaired: int
    lost: int
    open_ranges: list[dict[str, object]]
    lost_ranges: list[dict[str, object]]


class GapRepair:
    def __init__(
        self,
        *,
        registry: Registry,
        ingest: TelemetryIngest,
        publisher: Publisher,
        topics: Topics,
        rejects: InboundRejects | None = None,
        grace_s: float = 0.5,
        reply_timeout_s: float = 3.0,
        max_unanswered: int = 3,
        window_s: float = 600.0,
        on_lost: Callable[[str, str, int, str], None] | None = None,
    ) -> None:
        #: told of every loss for good (robot, stream, messages, reason): the data_gap alarm
        self._on_lost = on_lost
        self._registry = registry
        self._ingest = ingest
        self._publisher = publisher
        self._topics = topics
        self._rejects = rejects
        self.grace_s = grace_s
        self.reply_timeout_s = reply_timeout_s
        self.max_unanswered = max_unanswered
        self.window_s = window_s
        self.streams: dict[tuple[str, str], StreamGaps] = {}
        #: robots seen online; of them, those whose agent connected while this server listened (the online
        #: status came live, not retained); runs (boot ids) that began while their robot was so connected
        self._online: set[str] = set()
        self._connected_live: set[str] = set()
        self._boots_seen: dict[str, set[str]] = {}
        self._born_live: set[tuple[str, str]] = set()
        self._new_gaps: dict[tuple[str, str, str], list[tuple[int, int]]] = {}
        self._rl = RateLimitedLogger(log)
        self.requests_sent = 0
        self.replies = 0
        self.replayed_refused = 0
        self.replies_unsolicited = 0

    # -- live telemetry (every message: keep it cheap) -------------------------------------------------
    def robot_status(self, robot_id: str, online: bool, retained: bool) -> None:
        """Every status message. An agent that connects while this server listens (online after offline, the
        status live) starts its runs where the server sees them from seq 0: a run first seen at seq k > 0
        lost 0..k-1. After a server restart the status comes retained, and a run's first message seen then
        proves nothing (what came before may well be stored), nor does a periodic status refresh."""
        if not online:
            self._online.discard(robot_id)
            self._connected_live.discard(robot_id)
        elif robot_id not in self._online:
            self._online.add(robot_id)
            if retained:
                self._connected_live.discard(robot_id)
            else:
                self._connected_live.add(robot_id)

    def _run_began_live(self, robot_id: str, boot: str) -> bool:
        seen = self._boots_seen.setdefault(robot_id, set())
        if boot not in seen:
            seen.add(boot)
            if robot_id in self._connected_live:
                self._born_live.add((robot_id, boot))
        return (robot_id, boot) in self._born_live

    def observe(self, robot_id: str, stream: str, boot: str | None, seq: int, received: float) -> None:
        key = (robot_id, stream)
        sg = self.streams.get(key)
        if sg is None:
            sg = self.streams[key] = StreamGaps()
        bg = sg.boots.get(boot or "")
        if bg is None:
            bg = sg.boot(boot or "")
            if boot and self._run_began_live(robot_id, boot) and seq > 0:
                bg.last_seq = -1  # its first messages never arrived: seq 0..k-1 become a gap
        gap = bg.observe(seq, received)
        if gap is None:
            return
        self._new_gaps.setdefault((robot_id, stream, bg.boot), []).append(gap)
        if not boot:  # an agent without a boot id cannot be asked: the gap is lost at once
            self._lose(robot_id, stream, bg, [gap], "no_boot_id", received)

    # -- periodic (the container's tick) ---------------------------------------------------------------
    def tick(self, now: float | None = None) -> None:
        now = time.time() if now is None else now
        self._report_new_gaps()
        for (robot_id, stream), sg in self.streams.items():
            for bg in list(sg.boots.values()):
                if bg.open or bg.inflight is not None:
                    self._step(robot_id, stream, bg, now)

    def _step(self, robot_id: str, stream: str, bg: BootGaps, now: float) -> None:
        expired = [(r.lo, r.hi) for r in bg.open if now - r.since > self.window_s]
        if expired:
            self._lose(robot_id, stream, bg, expired, "expired", now)
        fl = bg.inflight
        if fl is not None:
            if now - fl.sent_at < self.reply_timeout_s:
                return
            bg.inflight = None
            if not fl.got_reply:
                bg.unanswered += 1
                if bg.unanswered >= self.max_unanswered:
                    bg.unanswered = 0
                    self._lose(robot_id, stream, bg, fl.ranges, "no_answer", now)
        st = self._registry.get(robot_id)
        if not bg.open or not bg.boot or st is None or not st.online:
            return  # offline robots are asked again when they are back (or the window expires the gap)
        ranges = bg.requestable(now, self.grace_s, MAX_REPAIR_SEQS, MAX_REPAIR_RANGES)
        if not ranges:
            return
        req = new_repair_request(bg.boot, stream, ranges)
        bg.inflight = InFlight(req.id, now, ranges)
        self._publisher.publish(self._topics.repair_request(robot_id), encode_repair_request(req), qos=QOS_REPAIR)
        self.requests_sent += 1

    def _report_new_gaps(self) -> None:
        for (robot_id, stream, boot), ranges in self._new_gaps.items():
            missing = sum(hi - lo + 1 for lo, hi in ranges)
            self._registry.event(
                "telemetry_gap",
                robot_id,
                {
                    "stream": stream,
                    "boot": boot,
                    "missing": missing,
                    "ranges": [list(r) for r in ranges[:EVENT_RANGES]],
                },
            )
            self._rl.warning(
                f"gap:{robot_id}",
                "robot %s stream %s: %d messages missing (%s%s); repairing",
                robot_id,
                stream,
                missing,
                ranges[0],
                ", ..." if len(ranges) > 1 else "",
            )
        self._new_gaps.clear()

    def _lose(
        self, robot_id: str, stream: str, bg: BootGaps, ranges: list[tuple[int, int]], reason: str, now: float
    ) -> None:
        before = len(bg.lost_ranges)
        n = bg.mark_lost(ranges, reason, now)
        if not n:
            return
        lost = [[r.lo, r.hi] for r in bg.lost_ranges[before:]][:EVENT_RANGES]
        if self._on_lost is not None and n:
            self._on_lost(robot_id, stream, n, reason)
        self._registry.event(
            "telemetry_lost", robot_id, {"stream": stream, "boot": bg.boot, "lost": n, "reason": reason, "ranges": lost}
        )
        self._rl.warning(
            f"lost:{robot_id}",
            "robot %s stream %s: %d messages lost for good (%s): %s",
            robot_id,
            stream,
            n,
            reason,
            lost[:3],
        )
        self._episode_done(robot_id, stream, bg, now)

    def _episode_done(self, robot_id: str, stream: str, bg: BootGaps, now: float) -> None:
        if bg.open or bg.episode_start is None:
            return
        if bg.episode_repaired:
            self._registry.event(
                "telemetry_repaired",
                robot_id,
                {
                    "stream": stream,
                    "boot": bg.boot,
                    "repaired": bg.episode_repaired,
                    "seconds": round(now - bg.episode_start, 3),
                },
            )
        bg.episode_start = None
        bg.episode_repaired = 0

    # -- replies (dispatcher) --------------------------------------------------------------------------
    def on_reply(self, robot_id: str, payload: bytes, received: float) -> None:
        """A robot's reply; raises ProtocolError (counted by the dispatcher) when it does not parse."""
        reply = decode_repair_reply(payload)
        self.replies += 1
        sg = self.streams.get((robot_id, reply.stream))
        bg = sg.boots.get(reply.boot) if sg is not None else None
        if sg is None or bg is None:
            self.replies_unsolicited += 1
            return
        # every message, not only the open ones: a reply delivered again (its rows given up, its ack withheld)
        # must be stored now; the unique key stores each message once
        messages, refused = replayed_messages(reply)
        if refused:  # the rest of the reply still counts
            self.replayed_refused += refused
            if self._rejects is not None:
                self._rejects.reject(
                    "repair_reply",
                    "bad_replayed_telemetry",
                    self._topics.repair_reply(robot_id),
                    f"{refused} replayed messages refused",
                )
        if messages:
            seen: set[int] = set()
            rows = []
            for m in messages:
                if m.seq not in seen:  # a reply listing a seq twice still stores it once
                    seen.add(m.seq)
                    rows.append((m.ts, m.seq, m.data))
            self._ingest.store_repaired(robot_id, reply.stream, rows, received)
            n = sum(hi - lo + 1 for lo, hi in bg.close(runs(sorted(seen))))
            bg.repaired += n
            bg.episode_repaired += n
        if reply.unavailable:
            reason = "unavailable" if bg.boot == sg.current else "agent_restarted"
            self._lose(robot_id, reply.stream, bg, list(reply.unavailable), reason, received)
        fl = bg.inflight
        if fl is not None and fl.request_id == reply.id:
            fl.got_reply = True
            bg.unanswered = 0
            if reply.final:
                bg.inflight = None
        self._episode_done(robot_id, reply.stream, bg, received)

    # -- reporting ---------------------------------------------------------------------------------------
    def summary(self, robot_id: str) -> dict[str, GapSummary]:
        out: dict[str, GapSummary] = {}
        for (rid, stream), sg in self.streams.items():
            if rid != robot_id:
                continue
            detected, open_n, repaired, lost = sg.totals()
            out[stream] = GapSummary(
                boot=sg.current or None,
                detected=detected,
                open=open_n,
                repaired=repaired,
                lost=lost,
                open_ranges=[{"boot": b.boot, "first": r.lo, "last": r.hi} for b in sg.boots.values() for r in b.open][
                    :EVENT_RANGES
                ],
                lost_ranges=[
                    {"boot": b.boot, "first": r.lo, "last": r.hi, "reason": r.reason, "at": r.at}
                    for b in sg.boots.values()
                    for r in b.lost_ranges
                ][-EVENT_RANGES:],
            )
        return out

    def merge_summary(self, robot_id: str, stats: list[StreamStats]) -> list[StreamStats]:
        """Adds the repair state to the stream summary (``GET /api/robots/{id}/streams``)."""
        summary = self.summary(robot_id)
        for s in stats:
            g = summary.get(s.stream)
            if g is not None:
                s.gaps_open, s.gaps_repaired, s.gaps_lost, s.boot = g.open, g.repaired, g.lost, g.boot
                s.open_ranges = [GapRange.model_validate(r) for r in g.open_ranges]
                s.lost_ranges = [GapRange.model_validate(r) for r in g.lost_ranges]
        return stats

    def stats(self) -> dict[str, int]:
        detected = open_n = repaired = lost = 0
        for d, o, r, lo in self.totals_by_stream().values():
            detected, open_n, repaired, lost = detected + d, open_n + o, repaired + r, lost + lo
        return {
            "detected": detected,
            "open": open_n,
            "repaired": repaired,
            "lost": lost,
            "requests_sent": self.requests_sent,
            "replies": self.replies,
            "replies_unsolicited": self.replies_unsolicited,
            "replayed_refused": self.replayed_refused,
        }

    def totals_by_stream(self) -> dict[str, tuple[int, int, int, int]]:
        """Per stream name over every robot: (detected, open, repaired, lost) messages."""
        out: dict[str, tuple[int, int, int, int]] = {}
        for (_rid, stream), sg in self.streams.items():
            t = sg.totals()
            prev = out.get(stream, (0, 0, 0, 0))
            out[stream] = (prev[0] + t[0], prev[1] + t[1], prev[2] + t[2], prev[3] + t[3])
        return out
