"""Helpers for the console tests of issue 21: touch devices, "fully inside the viewport", axe-core."""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

AXE = Path(__file__).resolve().parent / "firefox" / "node_modules" / "axe-core" / "axe.min.js"

PHONE = {"width": 390, "height": 844}
TABLET = {"width": 820, "height": 1180}
TOUCH = {"has_touch": True, "is_mobile": True, "device_scale_factor": 2}
DEVICES = {"phone": PHONE, "tablet": TABLET}


def open_page(page_factory: Any, path: str = "/", device: str | None = None, **options: Any) -> tuple[Any, Any]:
    """A logged-in page at ``path`` (on a touch ``device`` when given) once the live connection is up."""
    if device is not None:
        page, rec = page_factory(DEVICES[device]["width"], DEVICES[device]["height"], **TOUCH, **options)
    else:
        page, rec = page_factory(**options)
    page.goto(path)
    page.wait_for_function("() => window.fleetDebug && window.fleetDebug.wsConnected()")
    return page, rec


def inside_viewport(page: Any, selector: str) -> dict[str, float]:
    """The element's box; asserts it is visible and lies fully inside the viewport as it is now."""
    box = page.evaluate(
        """(sel) => { const e = document.querySelector(sel); if (!e) return null;
             const r = e.getBoundingClientRect(); const s = getComputedStyle(e);
             return {x: r.x, y: r.y, right: r.right, bottom: r.bottom, w: r.width, h: r.height,
                     vw: innerWidth, vh: innerHeight, visible: s.visibility !== 'hidden' && s.display !== 'none'}; }""",
        selector,
    )
    assert box is not None, f"{selector} missing"
    assert box["visible"] and box["w"] > 0 and box["h"] > 0, (selector, box)
    assert box["x"] >= 0 and box["y"] >= 0 and box["right"] <= box["vw"] and box["bottom"] <= box["vh"], (selector, box)
    return box


def no_horizontal_overflow(page: Any) -> None:
    widths = page.evaluate("() => [document.documentElement.scrollWidth, innerWidth]")
    assert widths[0] <= widths[1], f"page is {widths[0]} px wide in a {widths[1]} px viewport"


def axe_violations(page: Any, impacts: tuple[str, ...] = ("serious", "critical")) -> list[dict[str, Any]]:
    """axe-core's violations of ``impacts`` on the page as it is now (WCAG 2.x A/AA rules and best practice)."""
    if not AXE.is_file():
        pytest.fail("axe-core missing: `make test` runs npm ci in tests/frontend/firefox")
    if not page.evaluate("() => typeof window.axe === 'object'"):
        # run as the test's own script, not added as a <script> (Playwright's add_script_tag inlines the file):
        # the page's Content-Security-Policy refuses inline scripts, and holds no evaluate of a test to it
        page.evaluate(f"(() => {{\n{AXE.read_text()}\n}})()")
    result = page.evaluate("async () => (await axe.run(document, {resultTypes: ['violations']})).violations")
    return [
        {"id": v["id"], "impact": v["impact"], "help": v["help"], "nodes": [n["target"] for n in v["nodes"]][:5]}
        for v in result
        if v["impact"] in impacts
    ]


#: resolves once the robot list's DOM changed (its 1 s refresh re-renders it: "3 s ago" ages every second)
_LIST_RENDERED = """() => new Promise((resolve, reject) => {
  const body = document.querySelector('[data-testid^=robot-row-]').parentElement;
  const obs = new MutationObserver(() => { obs.disconnect(); resolve(true); });
  obs.observe(body, {childList: true, subtree: true, characterData: true, attributes: true});
  setTimeout(() => { obs.disconnect(); reject(new Error('the robot list did not re-render within 5 s')); }, 5000);
})"""


def wait_list_render(page: Any) -> None:
    """Return after the robot list has re-rendered once: whatever a refresh would undo is undone by then."""
    page.evaluate(_LIST_RENDERED)


def wait_frames(page: Any, frames: int = 3) -> None:
    """Return after ``frames`` animation frames: layout, ResizeObserver callbacks and the rAF redraws they
    schedule have all run for what happened before the call."""
    page.evaluate(
        "(n) => new Promise((resolve) => { const step = (k) => k ? requestAnimationFrame(() => step(k - 1))"
        " : resolve(true); step(n); })",
        frames,
    )


def watch_event(page: Any, kind: str) -> None:
    """Count ``kind`` events reaching window (bubble phase, registered after the page's own listeners): once
    one is counted, the page's handlers for it have run (same dispatch)."""
    page.evaluate(
        "(kind) => { window.__seen = window.__seen || {}; window.__seen[kind] = 0;"
        " window.addEventListener(kind, () => { window.__seen[kind]++; }); }",
        kind,
    )


def wait_event_handled(page: Any, kind: str, count: int = 1) -> None:
    """Return once ``count`` ``kind`` events reached window (see :func:`watch_event`)."""
    page.wait_for_function("([kind, n]) => (window.__seen?.[kind] ?? 0) >= n", arg=[kind, count])


#: each selector's box as [x, y, width, height], or null when it is missing or not rendered
BOXES_JS = """(sels) => sels.map((sel) => {
  const e = document.querySelector(sel);
  if (!e || !e.offsetParent) return null;
  const r = e.getBoundingClientRect();
  return [r.x, r.y, r.width, r.height]; })"""
_BOXES_SETTLED_JS = (
    "(sels) => { const now = JSON.stringify((" + BOXES_JS + ")(sels));"
    " const same = window.__boxesSeen === now; window.__boxesSeen = now; return same; }"
)


def boxes(page: Any, controls: dict[str, str]) -> dict[str, list[float]]:
    """Each named control's box (``{name: selector}``), measured in one script task; all must be rendered."""
    values = page.evaluate(BOXES_JS, list(controls.values()))
    found = dict(zip(controls, values, strict=True))
    missing = [name for name, box in found.items() if box is None]
    assert not missing, f"not on the page: {missing}"
    return found


def wait_boxes_settled(page: Any, selectors: list[str]) -> None:
    """Return once two reads of the boxes, one poll apart, agree: a layout pass or a transition in progress
    is over, so a later comparison measures only what happens after this call."""
    page.evaluate("() => { window.__boxesSeen = undefined; }")
    page.wait_for_function(_BOXES_SETTLED_JS, arg=selectors)


def wait_held(page: Any, held: list[Any], count: int, what: str) -> None:
    """Return once ``count`` requests have been held by a ``page.route`` handler that appends to ``held``."""
    deadline = time.monotonic() + 10
    while len(held) < count:
        assert time.monotonic() < deadline, f"the page sent {len(held)} {what}, expected {count}"
        page.wait_for_timeout(20)  # lets Playwright dispatch the route events


def answer_held(page: Any, route: Any, body: str, url_part: str) -> None:
    """Answer a held request with a JSON ``body`` and return once the page has handled the reply."""
    with page.expect_event("requestfinished", predicate=lambda r: url_part in r.url):
        route.fulfill(status=200, content_type="application/json", body=body)
    wait_frames(page, 3)  # the fetch's promise and the render it runs are done by then


#: frontend/js/drive/commandlog.js's HOLD_GAP_S: renewals this close together are one row of the log
HOLD_GAP_S = 0.5
#: the multiplication sign the log writes after a count
TIMES = "\u00d7"


def hold_groups(cmds: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """A source's drive renewals (oldest first) as the command log groups them: a renewal more than
    ``HOLD_GAP_S`` after the one before starts a new row (the robot's own deadman stopped it in between: a page
    or server stalled on a loaded machine, seen in Firefox). The rows the page must show, from the server's
    record."""
    groups: list[list[dict[str, Any]]] = []
    for c in sorted(cmds, key=lambda c: c["ts"]):
        if groups and c["ts"] - groups[-1][-1]["ts"] <= HOLD_GAP_S:
            groups[-1].append(c)
        else:
            groups.append([c])
    return groups


def hold_ends(cmds: list[dict[str, Any]]) -> str:
    """How a hold's renewals ended, as its row says it: "24x done" (" · 1x expired": a renewal that came late, in
    a stall of the machine, is refused by the robot and counted in the same row), statuses in order of first
    appearance."""
    counts = Counter(c["status"] for c in cmds)
    return " · ".join(f"{n}{TIMES} {status}" for status, n in counts.items())
