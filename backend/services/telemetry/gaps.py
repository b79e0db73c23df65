"""Per-stream gap bookkeeping for gap repair: which ``seq`` ranges are open, repaired or lost.

Pure data, no I/O: :mod:`backend.services.telemetry.repair` drives it. One :class:`BootGaps` per (robot, stream,
boot), because ``seq`` starts again at 0 when an agent restarts. A gap opens when a message's ``seq`` jumps
past the last one seen; a seq in an open gap closes that part of it when the original arrives late
(``late``), when a repair reply brings it (``repaired``), or it is given up (``lost``, with a reason).
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: lost ranges remembered per boot (the counts are kept whatever the number of ranges)
MAX_LOST_RANGES = 100
#: open ranges per boot; beyond this the oldest are recorded as lost ("too_many_gaps")
MAX_OPEN_RANGES = 1000


@dataclass(slots=True)
class OpenRange:
    lo: int
    hi: int
    #: server clock when the gap was seen
    since: float

    @property
    def size(self) -> int:
        return self.hi - self.lo + 1


@dataclass(slots=True)
class LostRange:
    lo: int
    hi: int
    reason: str
    at: float


@dataclass
class InFlight:
    request_id: str
    sent_at: float
    ranges: list[tuple[int, int]]
    got_reply: bool = False


@dataclass
class BootGaps:
    boot: str
    last_seq: int | None = None
    open: list[OpenRange] = field(default_factory=list)
    lost_ranges: list[LostRange] = field(default_factory=list)
    detected: int = 0
    repaired: int = 0
    lost: int = 0
    late: int = 0
    inflight: InFlight | None = None
    #: requests in a row that got no reply at all
    unanswered: int = 0
    #: server clock of the first gap of the current episode (until nothing is open again)
    episode_start: float | None = None
    episode_repaired: int = 0

    @property
    def open_count(self) -> int:
        return sum(r.size for r in self.open)

    def observe(self, seq: int, now: float) -> tuple[int, int] | None:
        """A live message: returns the new open range when ``seq`` jumped past the last one."""
        last = self.last_seq
        if last is None or seq == last + 1:
            self.last_seq = seq
            return None
        if seq > last + 1:
            gap = (last + 1, seq - 1)
            self.open.append(OpenRange(gap[0], gap[1], now))
            self.detected += gap[1] - gap[0] + 1
            if self.episode_start is None:
                self.episode_start = now
            self.last_seq = seq
            if len(self.open) > MAX_OPEN_RANGES:
                oldest = self.open[0]
                self.mark_lost([(oldest.lo, oldest.hi)], "too_many_gaps", now)
            return gap
        # at or below the last one: a redelivery, or an original that was late (it fills an open gap)
        if self.close([(seq, seq)]):
            self.late += 1
        elif self._is_lost(seq):
            self._unlose(seq)
            self.late += 1
        return None

    def close(self, ranges: list[tuple[int, int]]) -> list[tuple[int, int]]:
        """Take ``ranges`` out of the open gaps; returns the parts that were open (inclusive runs)."""
        closed: list[tuple[int, int]] = []
        for lo, hi in ranges:
            kept: list[OpenRange] = []
            for r in self.open:
                if r.hi < lo or r.lo > hi:
                    kept.append(r)
                    continue
                a, b = max(lo, r.lo), min(hi, r.hi)
                closed.append((a, b))
                if r.lo < a:
                    kept.append(OpenRange(r.lo, a - 1, r.since))
                if b < r.hi:
                    kept.append(OpenRange(b + 1, r.hi, r.since))
            self.open = kept
        return closed

    def is_open(self, seq: int) -> bool:
        return any(r.lo <= seq <= r.hi for r in self.open)

    def mark_lost(self, ranges: list[tuple[int, int]], reason: str, now: float) -> int:
        """Give up on the open parts of ``ranges``; returns how many seq numbers that was."""
        n = 0
        for a, b in sorted(self.close(ranges)):
            self.lost_ranges.append(LostRange(a, b, reason, now))
            n += b - a + 1
        if len(self.lost_ranges) > MAX_LOST_RANGES:
            del self.lost_ranges[: len(self.lost_ranges) - MAX_LOST_RANGES]
        self.lost += n
        return n

    def _is_lost(self, seq: int) -> bool:
        return any(r.lo <= seq <= r.hi for r in self.lost_ranges)

    def _unlose(self, seq: int) -> None:
        """An original recorded as lost arrived after all: it is stored, so it is no longer lost."""
        kept: list[LostRange] = []
        for r in self.lost_ranges:
            if r.lo <= seq <= r.hi:
                if r.lo < seq:
                    kept.append(LostRange(r.lo, seq - 1, r.reason, r.at))
                if seq < r.hi:
                    kept.append(LostRange(seq + 1, r.hi, r.reason, r.at))
            else:
                kept.append(r)
        self.lost_ranges = kept
        self.lost -= 1

    def requestable(self, now: float, grace_s: float, max_seqs: int, max_ranges: int) -> list[tuple[int, int]]:
        """Open ranges seen at least ``grace_s`` ago (a late original may still come), oldest first."""
        out: list[tuple[int, int]] = []
        budget = max_seqs
        for r in self.open:
            if now - r.since < grace_s or budget <= 0 or len(out) >= max_ranges:
                break
            hi = min(r.hi, r.lo + budget - 1)
            out.append((r.lo, hi))
            budget -= hi - r.lo + 1
        return out


def runs(seqs: list[int]) -> list[tuple[int, int]]:
    """Seq numbers as sorted inclusive runs."""
    out: list[tuple[int, int]] = []
    for s in sorted(seqs):
        if out and s == out[-1][1] + 1:
            out[-1] = (out[-1][0], s)
        else:
            out.append((s, s))
    return out


#: boots remembered per stream; older ones without open gaps are folded into the stream's totals
MAX_BOOTS = 8


@dataclass
class StreamGaps:
    """All boots of one (robot, stream); ``current`` is the boot of the newest message."""

    boots: dict[str, BootGaps] = field(default_factory=dict)
    current: str | None = None
    restarts: int = 0
    #: (detected, repaired, lost) of boots no longer remembered
    retired: tuple[int, int, int] = (0, 0, 0)

    def boot(self, boot: str) -> BootGaps:
        bg = self.boots.get(boot)
        if bg is None:
            bg = self.boots[boot] = BootGaps(boot)
            previous, self.current = self.current, boot
            if previous is not None:
                self.restarts += 1
                self._forget_old_boots()
        return bg

    def _forget_old_boots(self) -> None:
        for key in list(self.boots):
            if len(self.boots) <= MAX_BOOTS:
                return
            b = self.boots[key]
            if key != self.current and not b.open and b.inflight is None:
                d, r, lost = self.retired
                self.retired = (d + b.detected, r + b.repaired, lost + b.lost)
                del self.boots[key]

    def totals(self) -> tuple[int, int, int, int]:
        """(detected, open, repaired, lost) over every boot."""
        bs = self.boots.values()
        d, r, lost = self.retired
        return (
            d + sum(b.detected for b in bs),
            sum(b.open_count for b in bs),
            r + sum(b.repaired for b in bs),
            lost + sum(b.lost for b in bs),
        )
