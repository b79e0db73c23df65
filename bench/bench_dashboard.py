"""Dashboard under fleet load: N synthetic robots x R Hz position telemetry through broker and server into
the real dashboard in headless Chromium. Measures animation-frame intervals (Performance API: p95 must
stay <= 33 ms, i.e. >= 30 fps), the map's Plotly render time per frame, and JS heap over time (no growth).

    .venv/bin/python bench/bench_dashboard.py [--robots 100] [--rate 20] [--seconds 300] [--motion circle|still]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_live import fleet_load
from bench.common import cpu_seconds, percentile, report, rss_mb, stack
from tests.frontend.conftest import CHROMIUM, CHROMIUM_ARGS

FRAME_PROBE = """() => {
  window.__frames = [];
  let last = performance.now();
  const tick = (t) => { window.__frames.push(t - last); last = t; requestAnimationFrame(tick); };
  requestAnimationFrame(tick);
}"""


def open_dashboard(p: Any, base_url: str, robots: int) -> tuple[Any, Any]:
    """(browser, page): the dashboard in headless Chromium at 1280x720, once it lists ``robots`` robots."""
    browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.goto(base_url + "/")
    page.wait_for_function(f"() => Object.keys(window.fleetDebug?.robots() ?? {{}}).length >= {robots}", timeout=60000)
    return browser, page


def run(args: argparse.Namespace) -> dict[str, Any]:
    from playwright.sync_api import sync_playwright

    # rendering is what is measured here: the demo mode (no login) keeps the browser setup trivial
    with stack(FLEET_AUTH="off") as (broker, server, _work):
        heap: list[tuple[float, float]] = []
        with (
            fleet_load(broker.host, broker.port, args.robots, args.rate, args.seconds + 30, motion=args.motion),
            sync_playwright() as p,
        ):
            browser, page = open_dashboard(p, server.base_url, args.robots)
            page.wait_for_timeout(2000)
            page.evaluate(FRAME_PROBE)
            page.evaluate("() => window.fleetDebug.frameTimes.splice(0)")
            cdp = page.context.new_cdp_session(page)
            cdp.send("Performance.enable")
            pid = server.proc.pid  # type: ignore[union-attr]
            cpu0, t0 = cpu_seconds(pid), time.monotonic()
            while time.monotonic() - t0 < args.seconds:
                time.sleep(min(5.0, args.seconds / 4))
                cdp.send("HeapProfiler.collectGarbage")
                metrics = {m["name"]: m["value"] for m in cdp.send("Performance.getMetrics")["metrics"]}
                heap.append((time.monotonic() - t0, metrics["JSHeapUsedSize"] / 1e6))
            frames = page.evaluate("() => window.__frames")
            render = page.evaluate("() => window.fleetDebug.frameTimes.slice()")
            renders = page.evaluate("() => window.fleetDebug.renders()")
            server_cpu = (cpu_seconds(pid) - cpu0) / (time.monotonic() - t0)
            server_rss = rss_mb(pid)
            browser.close()
    frames = frames[5:]
    first, last = heap[0][1], heap[-1][1]
    return {
        "robots": args.robots,
        "rate_hz": args.rate,
        "seconds": args.seconds,
        "motion": args.motion,
        "frame_p50_ms": percentile(frames, 50),
        "frame_p95_ms": percentile(frames, 95),
        "frame_p99_ms": percentile(frames, 99),
        "frames": len(frames),
        "map_render_p50_ms": percentile(render, 50),
        "map_render_p95_ms": percentile(render, 95),
        "map_renders": renders,
        "heap_first_mb": first,
        "heap_last_mb": last,
        "heap_samples": heap,
        "server_cpu_cores": server_cpu,
        "server_rss_mb": server_rss,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=100)
    p.add_argument("--rate", type=float, default=20.0)
    p.add_argument("--seconds", type=float, default=300.0)
    p.add_argument(
        "--motion",
        choices=("circle", "still"),
        default="circle",
        help="circle: every robot drives a small circle (full trails to draw); still: parked",
    )
    args = p.parse_args()
    r = run(args)
    growth = r["heap_last_mb"] - r["heap_first_mb"]
    ok = lambda c: "yes" if c else "NO"  # noqa: E731
    report(
        "dashboard",
        [
            ("frame interval p50 (ms)", f"{r['frame_p50_ms']:.1f}", "-", "-"),
            ("frame interval p95 (ms)", f"{r['frame_p95_ms']:.1f}", "<= 33", ok(r["frame_p95_ms"] <= 33)),
            ("map render p95 (ms)", f"{r['map_render_p95_ms']:.1f}", "-", "-"),
            (
                "JS heap first/last (MB)",
                f"{r['heap_first_mb']:.1f}/{r['heap_last_mb']:.1f}",
                "no growth",
                ok(growth < max(5.0, 0.2 * r["heap_first_mb"])),
            ),
            ("server CPU (cores)", f"{r['server_cpu_cores']:.2f}", "-", "-"),
        ],
        {k: v for k, v in r.items() if k != "heap_samples"} | {"heap_growth_mb": growth},
    )


if __name__ == "__main__":
    main()
