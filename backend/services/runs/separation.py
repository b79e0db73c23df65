"""Separation figures of a stretch of time (issue 31, "Visible and counted"; docs/runs.md, Separation): how
close the robots came to each other, measured from their stored positions, and how often their safety
filters stepped in, from their ``avoidance`` streams. Robotarium-style: the closest approach, and the episodes
under the site's safety distance (violations) and under two body radii (contacts), counted and timed.

Each pair is measured at every stored sample of either robot, the other's position linearly interpolated to
that sample's time, only where the other has a sample on each side within ``MAX_GAP_S`` (a robot that went
silent is not guessed at). The work is bounded before it starts: at most ``sample_cap(robots)`` positions a
robot (``PAIR_WORK_BUDGET`` sample evaluations over all pairs; a longer run is thinned evenly by the read),
vectorised with numpy, and run on a worker pool, never on the event loop (backend/api/separation.py).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from backend.schemas.separation import Approach, PairSeparation, RobotInterventions, SeparationStats
from backend.store.separation import RobotSamples
from fleet_protocol.neighbours import BODY_RADIUS_M

#: the other robot's samples around a sample must be at most this far from it to interpolate between them
MAX_GAP_S = 1.0
#: positions a robot at most, however few robots (a 30-minute run at 20 Hz)
MAX_SAMPLES_PER_ROBOT = 36_000
#: sample evaluations over all pairs: a robot's share is this / (robots x (robots - 1))
PAIR_WORK_BUDGET = 4_000_000
#: avoidance messages read a robot (at most 10 a second while an intervention lasts)
MAX_AVOIDANCE_PER_ROBOT = 50_000
#: a contact: the two bodies touch
CONTACT_M = 2 * BODY_RADIUS_M


def sample_cap(robots: int) -> int:
    """Positions read a robot: all pairs together stay within ``PAIR_WORK_BUDGET``."""
    if robots < 2:
        return MAX_SAMPLES_PER_ROBOT
    return max(100, min(MAX_SAMPLES_PER_ROBOT, PAIR_WORK_BUDGET // (robots * (robots - 1))))


@dataclass(frozen=True)
class Track:
    """One robot's positions in time order; ``gap_s``: the widest gap it is interpolated across."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    gap_s: float = MAX_GAP_S


def interpolate(track: Track, at: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The track's x and y at the times ``at`` (linear between its samples) and a mask of where that holds:
    a sample at that very time, or one on each side, each within ``gap_s``."""
    n = track.t.size
    if n == 0 or at.size == 0:
        empty = np.zeros(at.size)
        return empty, empty, np.zeros(at.size, dtype=bool)
    idx = np.searchsorted(track.t, at, side="right")  # t[idx - 1] <= at < t[idx]
    lo = np.clip(idx - 1, 0, n - 1)
    hi = np.clip(idx, 0, n - 1)
    t_lo, t_hi = track.t[lo], track.t[hi]
    exact = (idx > 0) & (t_lo == at)
    bracketed = (idx > 0) & (idx < n) & (at - t_lo <= track.gap_s) & (t_hi - at <= track.gap_s)
    span = t_hi - t_lo
    w = np.divide(at - t_lo, span, out=np.zeros(at.size), where=span > 0)
    w = np.where(exact, 0.0, w)
    x = track.x[lo] + w * (track.x[hi] - track.x[lo])
    y = track.y[lo] + w * (track.y[hi] - track.y[lo])
    return x, y, exact | bracketed


def pair_distances(a: Track, b: Track) -> tuple[np.ndarray, np.ndarray]:
    """Times and centre-to-centre distances of a pair, in time order: each of a's samples against b
    interpolated to it, and each of b's against a; samples where the other cannot be interpolated left out."""
    bx, by, b_ok = interpolate(b, a.t)
    ax, ay, a_ok = interpolate(a, b.t)
    t = np.concatenate([a.t[b_ok], b.t[a_ok]])
    d = np.concatenate(
        [np.hypot(a.x[b_ok] - bx[b_ok], a.y[b_ok] - by[b_ok]), np.hypot(b.x[a_ok] - ax[a_ok], b.y[a_ok] - ay[a_ok])]
    )
    order = np.argsort(t, kind="stable")
    return t[order], d[order]


def episodes_below(t: np.ndarray, d: np.ndarray, limit: float, gap_s: float = MAX_GAP_S) -> tuple[int, float]:
    """Episodes of a distance series under ``limit``: how many, and their total duration. An episode is a
    run of consecutive samples under it (a gap over ``gap_s`` between samples ends one); its ends lie where
    the distance crosses the limit, linearly between the sample under and the one before or after it."""
    if t.size == 0:
        return 0, 0.0
    below = d < limit
    if not below.any():
        return 0, 0.0
    dt = np.diff(t)
    joined = dt <= gap_s  # sample i and i + 1 belong to one stretch of data
    prev_below = np.concatenate([[False], below[:-1] & joined])
    next_below = np.concatenate([below[1:] & joined, [False]])
    starts = np.flatnonzero(below & ~prev_below)
    ends = np.flatnonzero(below & ~next_below)

    def crossing(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Where the distance crosses ``limit`` between samples i (under) and j (over), or t[i] when j is
        not a neighbour in the same stretch of data."""
        ok = (j >= 0) & (j < t.size)
        jj = np.clip(j, 0, t.size - 1)
        ok &= np.abs(t[jj] - t[i]) <= gap_s
        ok &= ~below[jj]
        frac = np.divide(limit - d[i], d[jj] - d[i], out=np.zeros(i.size), where=ok & (d[jj] != d[i]))
        return np.where(ok, t[i] + np.clip(frac, 0.0, 1.0) * (t[jj] - t[i]), t[i])

    begin = crossing(starts, starts - 1)
    finish = crossing(ends, ends + 1)
    return int(starts.size), float(np.sum(finish - begin))


def pair_separation(ids: tuple[str, str], a: Track, b: Track, min_separation_m: float) -> PairSeparation:
    t, d = pair_distances(a, b)
    out = PairSeparation(robots=ids, samples=int(t.size))
    if t.size == 0:
        return out
    i = int(np.argmin(d))
    out.closest_m, out.closest_ts = round(float(d[i]), 4), float(t[i])
    gap = max(a.gap_s, b.gap_s)
    out.violations, violation_s = episodes_below(t, d, min_separation_m, gap)
    out.contacts, contact_s = episodes_below(t, d, CONTACT_M, gap)
    out.violation_s, out.contact_s = round(violation_s, 3), round(contact_s, 3)
    return out


def interventions(messages: list[tuple[float, dict[str, Any]]], start: float) -> RobotInterventions:
    """A robot's ``avoidance`` messages in time order, as episodes: one starts with ``active`` when none is
    open, or when its ``duration_s`` went back (the previous one's ``cleared`` was lost), and ends with
    ``cleared`` (or its last message). It began ``duration_s`` before its first message (not before ``start``)."""
    out = RobotInterventions()
    opened: float | None = None
    last_ts = 0.0
    last_dur = 0.0

    def close(until: float) -> None:
        assert opened is not None
        out.duration_s += max(0.0, until - opened)

    for ts, data in messages:
        event = data.get("event")
        dur = _number(data.get("duration_s")) or 0.0
        dist = _number(data.get("distance_m"))
        if dist is not None and event == "active":
            out.min_distance_m = dist if out.min_distance_m is None else min(out.min_distance_m, dist)
        if event == "active":
            if opened is not None and dur < last_dur:
                close(last_ts)
                opened = None
            if opened is None:
                out.count += 1
                opened = max(start, ts - dur)
            last_ts, last_dur = ts, dur
        elif event == "cleared" and opened is not None:
            close(ts)
            opened = None
            last_dur = 0.0
    if opened is not None:
        close(last_ts)
    out.duration_s = round(out.duration_s, 3)
    return out


def _number(v: Any) -> float | None:
    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
        return float(v)
    return None


def separation(
    tracks: dict[str, Track],
    avoidance: dict[str, list[tuple[float, dict[str, Any]]]],
    min_separation_m: float,
    start: float,
    *,
    steps: dict[str, int] | None = None,
    truncated: frozenset[str] = frozenset(),
) -> SeparationStats:
    """Every pair's figures, the overall ones (the closest pair; counts and durations summed over pairs) and
    each robot's interventions. CPU work: run it on a worker pool."""
    stats = SeparationStats(min_separation_m=min_separation_m, contact_m=CONTACT_M)
    for (ia, a), (ib, b) in itertools.combinations(sorted(tracks.items()), 2):
        pair = pair_separation((ia, ib), a, b, min_separation_m)
        stats.pairs.append(pair)
        stats.violations += pair.violations
        stats.violation_s += pair.violation_s
        stats.contacts += pair.contacts
        stats.contact_s += pair.contact_s
        if pair.closest_m is not None and (stats.closest is None or pair.closest_m < stats.closest.distance_m):
            stats.closest = Approach(robots=pair.robots, distance_m=pair.closest_m, ts=pair.closest_ts or 0.0)
    stats.violation_s, stats.contact_s = round(stats.violation_s, 3), round(stats.contact_s, 3)
    for rid in sorted(avoidance):
        robot = interventions(avoidance[rid], start)
        robot.truncated = rid in truncated
        stats.interventions_by_robot[rid] = robot
        stats.interventions += robot.count
        stats.intervention_s += robot.duration_s
        if robot.min_distance_m is not None:
            low = stats.intervention_min_distance_m
            stats.intervention_min_distance_m = robot.min_distance_m if low is None else min(low, robot.min_distance_m)
    stats.intervention_s = round(stats.intervention_s, 3)
    stats.samples = {rid: int(tr.t.size) for rid, tr in sorted(tracks.items())}
    stats.step = {rid: (steps or {}).get(rid, 1) for rid in sorted(tracks)}
    return stats


def from_samples(samples: dict[str, RobotSamples], min_separation_m: float, start: float) -> SeparationStats:
    """The figures of what backend/store/separation.py read (a thinned robot is interpolated across gaps as
    much wider as it was thinned)."""
    tracks = {rid: Track(s.t, s.x, s.y, MAX_GAP_S * s.step) for rid, s in samples.items()}
    return separation(
        tracks,
        {rid: s.avoidance for rid, s in samples.items()},
        min_separation_m,
        start,
        steps={rid: s.step for rid, s in samples.items()},
        truncated=frozenset(rid for rid, s in samples.items() if s.avoidance_truncated),
    )
