"""The formation's error measured from stored positions (tests/examples/test_formation.py and the
``formation`` mission's test): for each stored fix of the leader, each follower's stored fix nearest in time
against the slot placed by the leader's fix and its heading over its last ten fixes."""

from __future__ import annotations

import bisect
import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fleet_client import FleetClient

Fix = Mapping[str, Any]  # position data: x, y, yaw


def fix_at(ts: Sequence[float], data: Sequence[Fix], t: float, within_s: float = 0.06) -> Fix | None:
    """The stored fix nearest to ``t`` (within ``within_s``)."""
    i = bisect.bisect_left(ts, t)
    best = min((j for j in (i - 1, i) if 0 <= j < len(ts)), key=lambda j: abs(ts[j] - t), default=None)
    return None if best is None or abs(ts[best] - t) > within_s else data[best]


def heading(data: Sequence[Fix], k: int, n: int = 10) -> tuple[float, float]:
    """The leader's heading over its last ``n`` stored fixes (a circular mean of their yaw)."""
    window = data[max(0, k - n + 1) : k + 1]
    hx = sum(math.cos(d["yaw"]) for d in window)
    hy = sum(math.sin(d["yaw"]) for d in window)
    norm = math.hypot(hx, hy) or 1.0
    return hx / norm, hy / norm


@dataclass
class FormationErrors:
    #: per follower, its distance from its slot at each matched leader fix (m)
    slot: dict[str, list[float]]
    #: per matched instant, the worst deviation of a triangle side (leader-follower or follower-follower)
    #: from its nominal length (m); empty unless there are exactly two followers
    sides: list[float]

    def summary(self, name: str) -> tuple[float, float, float]:
        """(mean, p95, max) of a follower's slot error."""
        errs = self.slot[name]
        return statistics.fmean(errs), sorted(errs)[int(0.95 * len(errs))], max(errs)


def formation_errors(
    lead_ts: Sequence[float],
    lead: Sequence[Fix],
    tracks: Mapping[str, tuple[Sequence[float], Sequence[Fix]]],
    slots: Mapping[str, tuple[float, float]],
) -> FormationErrors:
    """Slot errors of the followers in ``tracks`` ((ts, data) of their stored fixes) around the leader."""
    errors: dict[str, list[float]] = {name: [] for name in tracks}
    sides: list[float] = []
    names = list(tracks)
    for k, t in enumerate(lead_ts):
        hx, hy = heading(lead, k)
        here = {name: fix_at(*tracks[name], t) for name in names}
        for name in names:
            me = here[name]
            if me is None:
                continue
            fwd, left = slots[name]
            sx = lead[k]["x"] + fwd * hx - left * hy
            sy = lead[k]["y"] + fwd * hy + left * hx
            errors[name].append(math.dist((me["x"], me["y"]), (sx, sy)))
        if len(names) == 2 and all(here[n] is not None for n in names):
            a, b = names
            pa, pb = (here[a]["x"], here[a]["y"]), (here[b]["x"], here[b]["y"])  # type: ignore[index]
            pc = (lead[k]["x"], lead[k]["y"])
            sides.append(
                max(
                    abs(math.dist(pc, pa) - math.hypot(*slots[a])),
                    abs(math.dist(pc, pb) - math.hypot(*slots[b])),
                    abs(math.dist(pa, pb) - math.dist(slots[a], slots[b])),
                )
            )
    return FormationErrors(errors, sides)


def slot_start(offset: tuple[float, float], radius: float) -> tuple[float, float]:
    """A slot's position when the leader stands at (radius, 0) heading +y (examples/formation.py's circle
    path starts there, counter-clockwise)."""
    ox, oy = offset
    return radius - oy, ox


def stored_track(fleet: FleetClient, rid: str, start: float, end: float) -> tuple[list[float], list[dict[str, Any]]]:
    """A robot's stored fixes in [start, end]: (their ts, their data)."""
    rows = list(fleet.history_rows(rid, "position", start=start, end=end))
    return [r["ts"] for r in rows], [r["data"] for r in rows]
