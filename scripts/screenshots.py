"""`make screenshots`: the fleet, robot, history, users, missions, runs and audit pages at 390x844 (phone,
touch), 820x1180 (tablet, touch) and 1280x720 (laptop), written to docs/screenshots/<page>-<width>x<height>.png.

Not part of the test suite: it runs `scripts/demo.py` (broker, server with authentication on, three
simulated robots with cameras), logs in as the admin the demo prints, drives a robot for a moment so the
map shows trails and history has data, raises an alarm on every robot (a "battery low" threshold above
full) so each page shows its banner, and drives Debian's Chromium with Playwright. Ctrl-C-safe: the
demo is stopped in every case.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "screenshots"
CHROMIUM = os.environ.get("FLEET_TEST_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-dev-shm-usage",
]
SIZES = [(390, 844, True), (820, 1180, True), (1280, 720, False)]
PAGES = {
    "fleet": "/",
    "robot": "/robots/snail-2",
    "history": "/history?robots=snail-1,snail-2&stream=position",
    "users": "/users",
    "missions": "/missions",
    "runs": "/runs",
    "audit": "/audit",
}


def start_demo(state: Path) -> tuple[subprocess.Popen[str], dict[str, str]]:
    """The demo with authentication on; returns it and its summary fields once it printed "Ready."."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("FLEET_")}
    env.update(FLEET_AUTH="on", FLEET_DEMO_DIR=str(state), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [
            sys.executable,
            str(ROOT / "scripts" / "demo.py"),
            "--port",
            "0",
            "--broker-port",
            "0",
            "--camera",
            "--no-browser-hint",
        ],
        cwd=ROOT,
        env=env,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    lines: queue.Queue[str | None] = queue.Queue()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    fields: dict[str, str] = {}
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=1)
        except queue.Empty:
            continue
        if line is None:
            raise RuntimeError("the demo exited before it was ready")
        words = line.split()
        if line.startswith("  dashboard"):
            fields["url"] = words[1].rstrip("/").replace("localhost", "127.0.0.1")
        elif line.startswith("  auth") and "admin token" in line:
            fields["token"] = words[-1]
        elif line.startswith("  log in as"):
            fields["username"], fields["password"] = words[3], words[5]
        elif line.startswith("Ready."):
            return proc, fields
    raise RuntimeError("the demo did not get ready within 180 s")


def post(url: str, token: str, body: dict[str, Any], method: str = "POST") -> Any:
    req = urllib.request.Request(
        url,
        data=json.dumps(body).encode(),
        method=method,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "application/json"},
    )
    with urllib.request.urlopen(req, timeout=10) as answer:
        return json.loads(answer.read() or b"null")


def start_mission(fields: dict[str, str]) -> None:
    """A coverage sweep of the pool by snail-3 (the robot no command drove, so no lease holds it), running while
    the pages are shot: the fleet map and the missions page show its plan and swept area. A robot just online
    may not have synchronised its clock yet: the mission is refused (422) until it has."""
    body = {"type": "coverage", "name": "pool sweep", "robots": ["snail-3"], "params": {"sweep_width_m": 0.4}}
    deadline = time.monotonic() + 90
    mission = None
    while True:
        try:
            mission = mission or post(f"{fields['url']}/api/missions", fields["token"], body)
            post(f"{fields['url']}/api/missions/{mission['id']}/start", fields["token"], {})
            return
        except urllib.error.HTTPError as exc:
            detail = exc.read().decode(errors="replace")[:500]
            if exc.code != 422 or time.monotonic() > deadline:
                raise RuntimeError(f"the screenshots' mission was refused: {exc.code} {detail}") from None
            time.sleep(2)


def shoot(fields: dict[str, str]) -> list[Path]:
    from playwright.sync_api import sync_playwright

    base = fields["url"]
    written = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            for width, height, touch in SIZES:
                ctx = browser.new_context(
                    viewport={"width": width, "height": height},
                    base_url=base,
                    has_touch=touch,
                    is_mobile=touch,
                    color_scheme="light",
                )
                page = ctx.new_page()
                page.goto("/login")
                page.get_by_test_id("login-username").fill(fields["username"])
                page.get_by_test_id("login-password").fill(fields["password"])
                page.get_by_test_id("login-password").press("Enter")
                page.wait_for_function("() => window.fleetDebug?.wsConnected()")
                for name, path in PAGES.items():
                    page.goto(path)
                    page.wait_for_function("() => window.fleetDebug?.wsConnected()")
                    if name == "fleet":
                        page.wait_for_function("() => Object.keys(window.fleetDebug.mapRobots()).length >= 3")
                        page.get_by_test_id("robot-row-snail-2").click()
                        page.evaluate("() => window.scrollTo(0, 0)")  # the click scrolled to the list
                    elif name == "robot":
                        page.wait_for_function("() => window.fleetDebug.camera().frames >= 3", timeout=20000)
                    elif name == "history":
                        page.wait_for_function("() => document.querySelector('#history-chart .main-svg')")
                    elif name == "missions":
                        page.wait_for_function(
                            "() => document.querySelector('[data-testid=mission-status]')?.dataset.state === 'running'"
                        )
                    elif name == "users":
                        page.locator("[data-testid=user-rows] tr").first.wait_for()
                    page.wait_for_timeout(1200)  # charts and the live layer settle (a picture, not a test)
                    target = OUT / f"{name}-{width}x{height}.png"
                    page.screenshot(path=str(target))
                    written.append(target)
                ctx.close()
        finally:
            browser.close()
    return written


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None).parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fleet-screenshots-") as state:
        proc, fields = start_demo(Path(state))
        try:
            for rid, command in (("snail-1", "turn_left"), ("snail-2", "move_forward")):
                post(
                    f"{fields['url']}/api/robots/{rid}/commands",
                    fields["token"],
                    {"command": command, "args": {"speed": 0.6, "duration_s": 3}},
                )
            start_mission(fields)  # before the alarm below: a robot whose battery reads low is not ready
            # an alarm showing on every page (its banner overlays the page under the top bar): every robot's
            # battery reads "low" against a threshold above full
            post(
                f"{fields['url']}/api/alarm-rules",
                fields["token"],
                {"kind": "battery_low", "params": {"below_pct": 101}},
                method="PUT",
            )
            time.sleep(8)  # the robots leave trails and stored telemetry, the mission a swept area, to show
            written = shoot(fields)
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
    for path in written:
        print(path.relative_to(ROOT))
    return 0


if __name__ == "__main__":
    sys.exit(main())
