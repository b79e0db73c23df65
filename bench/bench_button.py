"""Browser button press -> agent receipt, under fleet load.

N synthetic robots publish position at R Hz (the live bench's load process) while an operator's page in
headless Chromium presses and holds the forward button of a real simulated agent (``fleet-agent
--simulate``) K times. Press time: the ``pointerdown`` event's timestamp in the page (epoch, captured
before the drive pad's own handler). Receipt: the ``ts`` of the agent's ``accepted`` ack, stamped when the
agent handles the command. Browser, server and agent share this machine's clock.

    .venv/bin/python bench/bench_button.py [--robots 100] [--rate 20] [--presses 100]
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_dashboard import open_dashboard
from bench.bench_live import fleet_load
from bench.common import percentile, report, stack
from tests.support.procs import AgentProcess, wait_for

PRESS_PROBE = """() => {
  window.__presses = [];
  document.addEventListener('pointerdown', (ev) => {
    if (ev.target.closest('[data-testid=drive-forward]')) window.__presses.push(performance.timeOrigin + ev.timeStamp);
  }, true);
}"""


def receipt_latencies(presses_ms: list[float], commands: list[dict[str, Any]]) -> list[float]:
    """For each press, the first forward command created after it and its agent's ``accepted`` ack."""
    forward = sorted((c for c in commands if c["command"] == "move_forward"), key=lambda c: c["ts"])
    out: list[float] = []
    for press in (p / 1000 for p in presses_ms):
        first = next((c for c in forward if c["ts"] >= press), None)
        accepted = [a["ts"] for a in (first or {}).get("acks", []) if a["status"] == "accepted"]
        if accepted:
            out.append(accepted[0] - press)
    return out


def run(args: argparse.Namespace) -> dict[str, Any]:
    from playwright.sync_api import sync_playwright

    with stack(FLEET_AUTH="off") as (broker, server, work):
        agent = AgentProcess("button-1", broker, work)
        agent.start()
        with server.client() as c:
            wait_for(
                lambda: (
                    c.get("/api/robots/button-1").status_code == 200 and c.get("/api/robots/button-1").json()["online"]
                ),
                30,
                what="agent online",
            )
        rng = random.Random(1)
        with (
            fleet_load(broker.host, broker.port, args.robots, args.rate, args.presses * 1.5 + 60),
            sync_playwright() as p,
        ):
            browser, page = open_dashboard(p, server.base_url, args.robots + 1)  # the load's and the agent
            page.get_by_test_id("robot-row-button-1").click()
            page.wait_for_function("() => window.fleetDebug.selected() === 'button-1'")
            page.evaluate(PRESS_PROBE)
            button = page.locator("[data-testid=drive-forward]:visible")
            box = button.bounding_box()
            assert box is not None
            page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
            t0 = time.time()
            for _ in range(args.presses):
                page.mouse.down()
                page.wait_for_timeout(150)
                page.mouse.up()
                page.wait_for_timeout(rng.uniform(250, 450))  # the robot stops between presses
            presses = page.evaluate("() => window.__presses")
            browser.close()
            page_time = time.time() - t0
            time.sleep(1)  # the last acks
        with server.client() as c:
            commands = c.get("/api/robots/button-1/commands", params={"limit": 1000}).json()
        agent.stop()
    lat = receipt_latencies(presses, commands)
    return {
        "robots": args.robots,
        "rate_hz": args.rate,
        "presses": len(presses),
        "matched": len(lat),
        "p50_ms": percentile(lat, 50) * 1000,
        "p95_ms": percentile(lat, 95) * 1000,
        "p99_ms": percentile(lat, 99) * 1000,
        "max_ms": max(lat, default=float("nan")) * 1000,
        "seconds": page_time,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=100)
    p.add_argument("--rate", type=float, default=20.0)
    p.add_argument("--presses", type=int, default=100)
    args = p.parse_args()
    r = run(args)
    ok = lambda c: "yes" if c else "NO"  # noqa: E731
    report(
        "button",
        [
            ("press -> agent receipt p50 (ms)", f"{r['p50_ms']:.1f}", "-", "-"),
            ("press -> agent receipt p99 (ms)", f"{r['p99_ms']:.1f}", "<= 50", ok(r["p99_ms"] <= 50)),
            ("presses matched / made", f"{r['matched']}/{r['presses']}", "all", ok(r["matched"] == r["presses"])),
        ],
        r,
    )


if __name__ == "__main__":
    main()
