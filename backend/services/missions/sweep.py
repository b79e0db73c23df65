"""A coverage mission's swept area as a grid over its workable region, extended one track segment at a time.

The union of every robot's buffered track, rebuilt from the whole tracks, grows with the mission (tens of
thousands of points an hour): on the event loop it stalled every step of a long mission. Here the region is
cut into cells (an eighth of the sweep width, coarser when that would be more than ``MAX_CELLS``) and each
new track segment marks the cells whose centre it sweeps (within half the sweep width of it: the buffer with
round ends and joins, as before), with one bit per robot. The work of a segment is a few hundred cells,
whatever came before it. A cell's *weight* is the share of it inside the region (1 inside, 0 outside,
measured for the cells the region's edge crosses), so the swept area is a sum of weights and the covered
fraction a quotient; the swept area's geometry (GeoJSON, a re-plan) and the picture are drawn from the cells,
on the planner pool, in work bounded by the grid's size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import GeometryCollection, MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

#: cells across the sweep width (its edge is placed to within an eighth of the width). Not a whole number:
#: lanes a whole number of widths apart would put every strip's edge at the same place in its cells, and the
#: cells' over- or under-count along the edges would add up instead of cancelling (1.4 % in the tests)
CELLS_PER_WIDTH = 8.618
#: the most cells a mission's grid has (a larger area gets coarser cells): 8 MB with its weights
MAX_CELLS = 1_000_000
#: segment pieces marked at once (bounds the arrays of one batch to a few MB)
BATCH = 1024
#: sample points across an edge cell (each way) that measure its share inside the region
EDGE_SAMPLES = 8


@dataclass(frozen=True)
class Frame:
    """The grid's place: cell (row, col) covers x in [minx + col * rx, ...), y in [miny + row * ry, ...)."""

    minx: float
    miny: float
    rx: float
    ry: float
    nx: int
    ny: int

    @property
    def cell_m2(self) -> float:
        return self.rx * self.ry


def frame_of(region: BaseGeometry, width_m: float) -> Frame:
    """Cells of ``width_m / CELLS_PER_WIDTH`` (coarser to fit ``MAX_CELLS``) that tile the region's bounds
    exactly: a region's straight sides along the axes fall on cell edges."""
    minx, miny, maxx, maxy = region.bounds
    span_x, span_y = max(maxx - minx, 1e-9), max(maxy - miny, 1e-9)
    res = max(width_m / CELLS_PER_WIDTH, math.sqrt(span_x * span_y / MAX_CELLS))
    nx, ny = max(1, math.ceil(span_x / res - 1e-9)), max(1, math.ceil(span_y / res - 1e-9))
    while nx * ny > MAX_CELLS:  # rounding up both ways overshoots by a row or a column (a sliver: more)
        res *= 1.01
        nx, ny = max(1, math.ceil(span_x / res - 1e-9)), max(1, math.ceil(span_y / res - 1e-9))
    return Frame(minx, miny, span_x / nx, span_y / ny, nx, ny)


def _clip(a: np.ndarray, b: np.ndarray, lo: tuple[float, float], hi: tuple[float, float]) -> tuple[np.ndarray, ...]:
    """The parts of segments a->b inside the box lo..hi (Liang-Barsky): a far jump marks only the grid."""
    d = b - a
    t0, t1 = np.zeros(len(a)), np.ones(len(a))
    keep = np.ones(len(a), dtype=bool)
    for axis in (0, 1):
        for p, q in ((-d[:, axis], a[:, axis] - lo[axis]), (d[:, axis], hi[axis] - a[:, axis])):
            flat = p == 0
            keep &= ~(flat & (q < 0))
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.where(flat, 0.0, q / np.where(flat, 1.0, p))
            t0 = np.where(~flat & (p < 0), np.maximum(t0, r), t0)
            t1 = np.where(~flat & (p > 0), np.minimum(t1, r), t1)
    keep &= t0 <= t1
    a, d, t0, t1 = a[keep], d[keep], t0[keep], t1[keep]
    return a + d * t0[:, None], a + d * t1[:, None]


def _pieces(a: np.ndarray, b: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Segments a->b cut into pieces at most ``step`` long (a point stays a point)."""
    d = b - a
    n = np.maximum(1, np.ceil(np.hypot(d[:, 0], d[:, 1]) / step)).astype(np.int64)
    seg = np.repeat(np.arange(len(a)), n)
    k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    t0, t1 = k / n[seg], (k + 1) / n[seg]
    return a[seg] + d[seg] * t0[:, None], a[seg] + d[seg] * t1[:, None]


def capsule_cells(frame: Frame, a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
    """Flat indices (unique) of the cells whose centre lies within ``radius`` of a segment a[i]->b[i] (a
    point when a[i] == b[i]). Work: the segments' length inside the grid over the cell size, times a window
    of cells of fixed size per piece."""
    if not len(a):
        return np.zeros(0, dtype=np.int64)
    f = frame
    lo = (f.minx - radius, f.miny - radius)
    hi = (f.minx + f.nx * f.rx + radius, f.miny + f.ny * f.ry + radius)
    a, b = _clip(a, b, lo, hi)
    step = max(radius, f.rx, f.ry)
    a, b = _pieces(a, b, step)
    if not len(a):
        return np.zeros(0, dtype=np.int64)
    kx, ky = int((step + 2 * radius) / f.rx) + 2, int((step + 2 * radius) / f.ry) + 2
    out = []
    for s in range(0, len(a), BATCH):
        pa, pb = a[s : s + BATCH], b[s : s + BATCH]
        col0 = np.ceil((np.minimum(pa[:, 0], pb[:, 0]) - radius - f.minx) / f.rx - 0.5).astype(np.int64)
        row0 = np.ceil((np.minimum(pa[:, 1], pb[:, 1]) - radius - f.miny) / f.ry - 0.5).astype(np.int64)
        cols = col0[:, None] + np.arange(kx)  # (P, kx)
        rows = row0[:, None] + np.arange(ky)  # (P, ky)
        cx = (f.minx + (cols + 0.5) * f.rx)[:, None, :] - pa[:, 0, None, None]
        cy = (f.miny + (rows + 0.5) * f.ry)[:, :, None] - pa[:, 1, None, None]
        dx, dy = (pb[:, 0] - pa[:, 0])[:, None, None], (pb[:, 1] - pa[:, 1])[:, None, None]
        dd = dx * dx + dy * dy
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.clip(np.where(dd > 0, (cx * dx + cy * dy) / np.where(dd > 0, dd, 1.0), 0.0), 0.0, 1.0)
        hit = (cx - t * dx) ** 2 + (cy - t * dy) ** 2 <= radius * radius
        hit &= ((cols >= 0) & (cols < f.nx))[:, None, :] & ((rows >= 0) & (rows < f.ny))[:, :, None]
        p, i, j = np.nonzero(hit)
        out.append(rows[p, i] * f.nx + cols[p, j])
    return np.unique(np.concatenate(out))


def region_weights(region: BaseGeometry, frame: Frame) -> np.ndarray:
    """Each cell's share inside the region (float32, rows x cols): by its centre, and for the cells the
    region's edge may cross (their centre within half a diagonal of it) by ``EDGE_SAMPLES``² points."""
    f = frame
    inside = shapely.from_wkb(shapely.to_wkb(region))  # a copy of its own to prepare (others read the region)
    shapely.prepare(inside)
    xs = f.minx + (np.arange(f.nx) + 0.5) * f.rx
    ys = f.miny + (np.arange(f.ny) + 0.5) * f.ry
    weights = shapely.contains_xy(inside, *np.meshgrid(xs, ys)).astype(np.float32)
    rings = shapely.get_rings(shapely.get_parts(region))
    a = [np.asarray(shapely.get_coordinates(r))[:-1] for r in rings]
    b = [np.asarray(shapely.get_coordinates(r))[1:] for r in rings]
    if not a:
        return weights
    edge = capsule_cells(f, np.concatenate(a), np.concatenate(b), math.hypot(f.rx, f.ry) / 2 * (1 + 1e-9))
    sub = (np.arange(EDGE_SAMPLES) + 0.5) / EDGE_SAMPLES
    for s in range(0, len(edge), BATCH):
        cells = edge[s : s + BATCH]
        row, col = np.divmod(cells, f.nx)
        px = f.minx + (col[:, None, None] + sub[None, None, :]) * f.rx  # (n, 1, S)
        py = f.miny + (row[:, None, None] + sub[None, :, None]) * f.ry  # (n, S, 1)
        share = shapely.contains_xy(inside, *np.broadcast_arrays(px, py)).mean(axis=(1, 2))
        weights.ravel()[cells] = share
    return weights


class SweptGrid:
    """The cells of a region and which robots swept each (a bit per robot, up to 32)."""

    def __init__(self, region: BaseGeometry, width_m: float) -> None:
        self.region = region
        self.width = width_m
        self.frame = frame_of(region, width_m)
        self.weight = region_weights(region, self.frame)
        self.total = float(self.weight.sum(dtype=np.float64))
        self.owners = np.zeros((self.frame.ny, self.frame.nx), dtype=np.uint32)
        #: swept weight, in all and per robot bit
        self.covered = 0.0
        self.swept: dict[int, float] = {}
        #: cells marked by the last :meth:`add` (what it cost)
        self.last_cells = 0

    def add(self, bit: int, points: np.ndarray) -> None:
        """Robot ``bit`` swept along ``points`` (n x 2: consecutive track points; one point: a disc)."""
        a, b = (points[:-1], points[1:]) if len(points) > 1 else (points, points)
        flats = capsule_cells(self.frame, a, b, self.width / 2)
        self.last_cells = len(flats)
        if not len(flats):
            return
        mask = np.uint32(1 << bit)
        owners = self.owners.ravel()
        was = owners[flats]
        new = (was & mask) == 0
        flats, was = flats[new], was[new]
        weight = self.weight.ravel()[flats]
        self.swept[bit] = self.swept.get(bit, 0.0) + float(weight.sum(dtype=np.float64))
        self.covered += float(weight[was == 0].sum(dtype=np.float64))
        owners[flats] = was | mask

    def view(self) -> SweptView:
        """A copy of what is swept now, for the planner pool to draw or outline while the loop goes on."""
        return SweptView(self.region, self.width, self.frame, self.owners != 0, self.weight)


@dataclass(frozen=True)
class SweptView:
    region: BaseGeometry
    width: float
    frame: Frame
    #: rows x cols: swept by any robot
    swept: np.ndarray
    weight: np.ndarray

    def hits(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        """Whether each point (x, y arrays) lies in a swept cell (the picture's pixels)."""
        f = self.frame
        col = np.floor((gx - f.minx) / f.rx).astype(np.int64)
        row = np.floor((gy - f.miny) / f.ry).astype(np.int64)
        ok = (col >= 0) & (col < f.nx) & (row >= 0) & (row < f.ny)
        out = np.zeros(gx.shape, dtype=bool)
        out[ok] = self.swept[row[ok], col[ok]]
        return out

    def geometry(self) -> BaseGeometry:
        """The swept cells inside the region as a (multi)polygon, clipped to the region: its area is the swept
        weight's. Work bounded by the grid: a box per run of swept cells in a row, united."""
        f = self.frame
        mask = self.swept & (self.weight > 0)
        if not mask.any():
            return GeometryCollection()
        padded = np.zeros((f.ny, f.nx + 2), dtype=np.int8)
        padded[:, 1:-1] = mask
        step = np.diff(padded, axis=1)
        rows, starts = np.nonzero(step == 1)
        _, ends = np.nonzero(step == -1)
        x0, x1 = f.minx + starts * f.rx, f.minx + ends * f.rx
        y0, y1 = f.miny + rows * f.ry, f.miny + (rows + 1) * f.ry
        clipped = shapely.union_all(shapely.box(x0, y0, x1, y1)).intersection(self.region)
        parts = [p for p in shapely.get_parts(clipped) if isinstance(p, Polygon) and not p.is_empty]
        if not parts:  # cells that only touch the region (a line, a point where they meet)
            return GeometryCollection()
        return parts[0] if len(parts) == 1 else MultiPolygon(parts)


__all__ = ["Frame", "SweptGrid", "SweptView", "capsule_cells", "frame_of", "region_weights"]
