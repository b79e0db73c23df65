"""The coverage PNG decodes with an independent decoder (OpenCV's libpng), is georeferenced as its bounds
say, and shows exactly the swept part of the region green."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from shapely.geometry import LineString, box

from backend.services.missions.raster import MAX_PIXELS, SWEPT, UNSWEPT, coverage_png


def decode(png: bytes) -> np.ndarray:
    bgra = cv2.imdecode(np.frombuffer(png, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    assert bgra is not None and bgra.shape[2] == 4, "not a PNG libpng reads"
    return cv2.cvtColor(bgra, cv2.COLOR_BGRA2RGBA)


def test_the_swept_strip_is_green_where_it_is_and_nowhere_else() -> None:
    region = box(-1.0, -0.5, 1.0, 0.5).difference(box(0.5, -0.1, 0.7, 0.1))  # a hole: a keep-out
    swept = LineString([(-1.0, 0.25), (0.0, 0.25)]).buffer(0.1, cap_style="flat")
    r = coverage_png(region, swept, px_per_m=100)
    img = decode(r.png)
    assert img.shape == (r.height, r.width, 4) == (100, 200, 4)
    assert r.bounds == pytest.approx((-1.0, -0.5, 1.0, 0.5)) and r.resolution_m == pytest.approx(0.01)

    def pixel(x: float, y: float) -> tuple[int, ...]:
        col = int((x - r.bounds[0]) / r.resolution_m)
        row = int((r.bounds[3] - y) / r.resolution_m)  # row 0 at the top (maxy)
        return tuple(int(v) for v in img[row, col])

    assert pixel(-0.5, 0.25) == SWEPT
    assert pixel(-0.5, -0.25) == UNSWEPT  # below the strip: workable, not swept
    assert pixel(0.5, 0.25) == UNSWEPT  # past the strip's end
    assert pixel(0.6, 0.0)[3] == 0  # the hole is not part of the region: transparent
    green = np.all(img == SWEPT, axis=2).sum() * r.resolution_m**2
    assert green == pytest.approx(swept.intersection(region).area, rel=0.03)
    grey = np.all(img == UNSWEPT, axis=2).sum() * r.resolution_m**2
    assert green + grey == pytest.approx(region.area, rel=0.02)


def test_a_huge_resolution_is_lowered_to_fit_and_an_empty_region_is_one_transparent_pixel() -> None:
    r = coverage_png(box(0, 0, 40, 40), box(0, 0, 1, 1), px_per_m=500)
    assert r.width * r.height <= MAX_PIXELS * 1.01 and r.width == r.height
    assert decode(r.png).shape[:2] == (r.height, r.width)
    empty = coverage_png(box(0, 0, 0, 0), box(0, 0, 1, 1))
    assert decode(empty.png).tolist() == [[[0, 0, 0, 0]]]
