"""The vendored Plotly holds every trace type the console draws.

frontend/vendor/plotly.min.js is a custom bundle (scripts/plotly-bundle: 2 MB instead of the full 4.8 MB
that every page used to parse). A trace type added to the console but not to the bundle would fail only in
the browser, on the page that draws it, so this checks the source against the bundle's list.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BUNDLE_DIR = ROOT / "scripts" / "plotly-bundle"
VENDORED = ROOT / "frontend" / "vendor" / "plotly.min.js"

# Every trace type of plotly.js 4.1.1 (its lib/ folder), so a `type: "button"` is not taken for a trace.
_TRACE_NAMES = (
    "bar barpolar box candlestick carpet choropleth choroplethmap cone contour contourcarpet densitymap "
    "funnel funnelarea heatmap histogram histogram2d histogram2dcontour icicle image indicator isosurface "
    "mesh3d ohlc parcats parcoords pie quiver sankey scatter scatter3d scattercarpet scattergeo scattergl "
    "scattermap scatterpolar scatterpolargl scattersmith scatterternary splom streamtube sunburst surface "
    "table treemap violin volume waterfall"
)
PLOTLY_TRACE_TYPES = frozenset(_TRACE_NAMES.split())
TYPE_FIELD = re.compile(r"""\btype:\s*["'](\w+)["']""")


def _bundled() -> list[str]:
    return json.loads((BUNDLE_DIR / "traces.json").read_text())


def _drawn() -> set[str]:
    found: set[str] = set()
    for js in (ROOT / "frontend" / "js").rglob("*.js"):
        found |= {t for t in TYPE_FIELD.findall(js.read_text()) if t in PLOTLY_TRACE_TYPES}
    return found


def test_every_trace_type_the_console_draws_is_in_the_bundle() -> None:
    drawn = _drawn()
    # The check could fail: the console draws these today, and a type outside the list would be named here.
    assert {"scatter", "scattergl", "scatter3d"} <= drawn
    assert drawn - set(_bundled()) == set(), "add them to scripts/plotly-bundle/traces.json, then make plotly-bundle"


def test_the_vendored_file_was_built_from_the_list() -> None:
    banner = VENDORED.read_text(encoding="utf-8")[:300]
    assert f"custom bundle: {', '.join(_bundled())}." in banner, "run make plotly-bundle after changing traces.json"
    # strict, for the Content-Security-Policy (no 'unsafe-eval', no inline styles): its styles beside it
    assert "strict (no eval, no inline style)" in banner and (VENDORED.parent / "plotly.css").is_file()
