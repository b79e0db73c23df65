"""A mission's coverage as a PNG: the workable region rasterised with shapely (already a dependency, with
numpy under it), the swept cells of its grid (sweep.py) over it, written with zlib + struct, so the server
needs no imaging library.

Pixel (col, row) covers x in [minx + col * res, minx + (col + 1) * res) and y from the top down (row 0 is
``maxy``), as a map is drawn; a pixel's colour is decided at its centre.
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from backend.services.missions.sweep import SweptView

#: which of the points (x, y arrays) are swept
Hits = Callable[[np.ndarray, np.ndarray], np.ndarray]

#: colours (RGBA): outside the workable region transparent, workable but not swept grey, swept green
OUTSIDE = (0, 0, 0, 0)
UNSWEPT = (214, 218, 222, 255)
SWEPT = (46, 160, 67, 255)
#: the largest picture served (pixels): the resolution is lowered to fit
MAX_PIXELS = 4_000_000


@dataclass(frozen=True)
class Raster:
    png: bytes
    width: int
    height: int
    #: metres per pixel
    resolution_m: float
    #: (minx, miny, maxx, maxy) of the picture in site metres
    bounds: tuple[float, float, float, float]


def swept_png(view: SweptView | None, px_per_m: float = 100.0) -> Raster:
    """A mission's coverage picture: its region, and the cells of its grid that were swept (sweep.py; on the
    planner pool). None (no coverage mission): one transparent pixel."""
    if view is None:
        return coverage_png(Polygon(), Polygon(), px_per_m)
    return coverage_png(view.region, view.hits, px_per_m)


def coverage_png(region: BaseGeometry, swept: BaseGeometry | Hits, px_per_m: float = 100.0) -> Raster:
    """Rasterise ``region`` (grey) with ``swept`` (green: a geometry, or which points are swept) over it at
    ``px_per_m`` (lowered to fit MAX_PIXELS); an empty region gives a 1 x 1 transparent picture."""
    if region.is_empty:
        return Raster(_png(np.zeros((1, 1, 4), dtype=np.uint8)), 1, 1, 1.0, (0.0, 0.0, 0.0, 0.0))
    minx, miny, maxx, maxy = region.bounds
    span_x, span_y = max(maxx - minx, 1e-6), max(maxy - miny, 1e-6)
    res = 1.0 / px_per_m
    if (span_x / res) * (span_y / res) > MAX_PIXELS:
        res = math.sqrt(span_x * span_y / MAX_PIXELS)
    width, height = max(1, math.ceil(span_x / res)), max(1, math.ceil(span_y / res))
    xs = minx + (np.arange(width) + 0.5) * res
    ys = miny + height * res - (np.arange(height) + 0.5) * res  # row 0 at the top
    gx, gy = np.meshgrid(xs, ys)
    inside = shapely.contains_xy(region, gx, gy)
    if callable(swept):
        hit = swept(gx, gy) & inside
    else:
        hit = shapely.contains_xy(swept, gx, gy) & inside if not swept.is_empty else np.zeros_like(inside)
    pixels = np.zeros((height, width, 4), dtype=np.uint8)
    pixels[inside] = UNSWEPT
    pixels[hit] = SWEPT
    bounds = (minx, miny, minx + width * res, miny + height * res)
    return Raster(_png(pixels), width, height, res, bounds)


def _png(pixels: np.ndarray) -> bytes:
    """An 8-bit RGBA PNG of ``pixels`` (height x width x 4): signature, IHDR, one IDAT, IEND."""
    height, width, _ = pixels.shape
    rows = np.zeros((height, 1 + width * 4), dtype=np.uint8)  # filter byte 0 (None) before each row
    rows[:, 1:] = pixels.reshape(height, width * 4)
    header = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)  # 8 bits, RGBA, deflate, no filter, no interlace
    data = _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(rows.tobytes(), 6)) + _chunk(b"IEND", b"")
    return b"\x89PNG\r\n\x1a\n" + data


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


__all__ = ["Raster", "coverage_png", "swept_png"]
