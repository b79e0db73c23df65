"""The swept-area grid (backend/services/missions/sweep.py): its figures, its outline (the GeoJSON) and its
picture agree with each other and with the exact geometry, on a region whose edges cross its cells."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from shapely import affinity
from shapely.geometry import LineString, box

from backend.services.missions.raster import SWEPT, swept_png
from backend.services.missions.state import Coverage, MissionRobot, rings
from backend.services.missions.sweep import MAX_CELLS, SweptGrid
from tests.support.missions import lawn_track

WIDTH = 0.2


def test_the_outline_and_the_picture_show_what_the_figures_count() -> None:
    """A pool turned by 20° with a keep-out (every edge across the cells), two robots' tracks: the region's
    weights add up to its area, the covered fraction is the exact union's, the outline's area is the
    fraction's and lies in the region, and the PNG's green is the same area."""
    pool = affinity.rotate(box(-2, -2, 2, 2), 20, origin=(0, 0))
    hole = affinity.rotate(box(0.3, 0.3, 1.1, 0.9), 20, origin=(0, 0))
    region = pool.difference(hole)
    a = MissionRobot(robot_id="a", path=[], breaks=[], track=lawn_track(-2.4, 0.0, -2.4, 2.4, 0.3, seed=3))
    b = MissionRobot(robot_id="b", path=[], breaks=[], track=lawn_track(0.1, 2.4, -2.4, 2.4, 0.3, seed=4))
    cov = Coverage(rings(pool), rings(hole), WIDTH)
    for _ in range(10):
        cov.update([a, b])
    grid = cov.grid
    assert grid is not None
    assert grid.total * grid.frame.cell_m2 == pytest.approx(region.area, rel=2e-3)
    exact = LineString(a.track).buffer(WIDTH / 2).union(LineString(b.track).buffer(WIDTH / 2)).intersection(region)
    assert cov.fraction == pytest.approx(exact.area / region.area, abs=0.005)
    assert 0.3 < cov.fraction < 0.9
    view = cov.view()
    assert view is not None
    outline = view.geometry()
    assert outline.geom_type in ("Polygon", "MultiPolygon")
    assert outline.area == pytest.approx(cov.fraction * region.area, rel=2e-3)
    assert outline.difference(view.region.buffer(1e-9)).area == 0.0  # (its corners: the rings to 0.1 mm)
    cell = float(np.hypot(grid.frame.rx, grid.frame.ry))  # the strips' edges are placed to within a cell
    assert outline.difference(exact.buffer(cell)).area < 1e-6 and exact.difference(outline.buffer(cell)).area < 1e-6
    picture = swept_png(view, 100.0)
    rgba = cv2.cvtColor(cv2.imdecode(np.frombuffer(picture.png, np.uint8), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGRA2RGBA)
    green = np.all(rgba == SWEPT, axis=2).sum() * picture.resolution_m**2
    assert green == pytest.approx(outline.area, rel=0.01)


def test_a_jump_across_the_site_marks_only_the_grid_and_a_large_area_gets_coarser_cells() -> None:
    """A robot that reappears 2 km away (its track's next point) sweeps a strip across the grid, not 2 km of
    cells; an area whose cells at an eighth of the width would be 100 million has at most MAX_CELLS."""
    big = SweptGrid(box(0, 0, 300, 300), WIDTH)
    assert big.frame.nx * big.frame.ny <= MAX_CELLS
    assert big.frame.rx == pytest.approx(big.frame.ry, rel=0.01) and big.frame.rx > WIDTH
    big.add(0, np.array([[-1000.0, -1000.0], [1000.0, 1000.0]]))
    assert 0 < big.last_cells <= 3 * big.frame.nx  # the diagonal, a cell or two wide
    assert big.covered * big.frame.cell_m2 == pytest.approx(300 * 2**0.5 * WIDTH, rel=0.5)
