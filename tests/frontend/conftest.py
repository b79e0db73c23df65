"""Browser fixtures: one headless Debian Chromium per test module (Playwright), a fresh page per test
that records every request, and a fleet of three simulated robots behind a real server and broker."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from tests.backend.helpers import driveable, wait_robot
from tests.support.priority import nice_playwright_driver
from tests.support.procs import AgentProcess, ServerProcess

CHROMIUM = os.environ.get("FLEET_TEST_CHROMIUM", "/usr/bin/chromium")
#: what the tests launch: CHROMIUM, niced below the robots (tests/support/priority.py)
CHROMIUM_NICED = str(Path(__file__).with_name("chromium-niced"))
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
    "--disable-dev-shm-usage",
]
SCREENSHOTS = Path(__file__).resolve().parents[2] / "docs" / "screenshots"
#: Run in every page before its own scripts (Chromium here, Firefox in firefox_page.py): each
#: Content-Security-Policy violation becomes a console error, which fails the tests that assert none (neither
#: browser gives its own CSP report to Playwright's or puppeteer's console events), and is kept in
#: window.__cspViolations for tests/frontend/test_content_security_policy.py.
CSP_REPORTER = """window.__cspViolations = [];
document.addEventListener('securitypolicyviolation', (e) => {
  const where = `${e.sourceFile}:${e.lineNumber}:${e.columnNumber}`;
  const on = e.target instanceof Element ? ` on ${e.target.outerHTML.slice(0, 160)}` : '';
  const what = `CSP violation: ${e.effectiveDirective} ${e.blockedURI} ${where}${on}`;
  window.__cspViolations.push(what);
  console.error(what);
});"""
FLEET = {"snail-1": "-1,-0.8,0", "snail-2": "0.5,0.6,1.57", "snail-3": "1.2,-1,3.14"}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if "tests/frontend" in str(item.fspath):
            item.add_marker(pytest.mark.browser)


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """Module-scoped: Playwright's sync API runs an event loop in this thread while the browser lives,
    which would break later tests that call ``asyncio.run``."""
    if not Path(CHROMIUM).exists() and not shutil.which("chromium"):
        pytest.fail(f"{CHROMIUM} missing: install Debian's chromium (scripts/ensure-system-deps.sh)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        nice_playwright_driver()  # its relay below the robots too (tests/support/priority.py)
        b = p.chromium.launch(executable_path=CHROMIUM_NICED, args=CHROMIUM_ARGS, headless=True)
        try:
            yield b
        finally:
            b.close()


@dataclass
class Recorder:
    """Every request the page made and every response status, to prove nothing leaves localhost."""

    requests: list[str] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    console_errors: list[str] = field(default_factory=list)


@pytest.fixture
def page_factory(browser: Any, server: ServerProcess) -> Iterator[Callable[..., tuple[Any, Recorder]]]:
    contexts: list[Any] = []

    def _make(width: int = 1280, height: int = 720, *, logged_in: bool = True, **options: Any) -> tuple[Any, Recorder]:
        """A page in a fresh browser context: logged in as the admin, or (``logged_in=False``) anonymous;
        ``options`` go to the context (``has_touch=True, is_mobile=True`` for a phone or tablet)."""
        auth = server_browser_auth(server) if logged_in else {}
        ctx = browser.new_context(
            viewport={"width": width, "height": height}, base_url=server.base_url, **auth, **options
        )
        contexts.append(ctx)
        page = ctx.new_page()
        rec = Recorder()

        def on_response(r: Any) -> None:
            if r.status >= 400:
                rec.failures.append(f"{r.status} {r.url}")

        def on_console(m: Any) -> None:
            if m.type == "error":
                rec.console_errors.append(m.text)

        page.on("request", lambda r: rec.requests.append(r.url))
        page.on("response", on_response)
        page.on("console", on_console)
        page.on("pageerror", lambda e: rec.console_errors.append(str(e)))
        page.add_init_script(CSP_REPORTER)
        return page, rec

    try:
        yield _make
    finally:
        for ctx in contexts:
            ctx.close()


def server_browser_auth(server: ServerProcess) -> dict[str, Any]:
    """Context options that authenticate the browser when the server runs with authentication."""
    auth = getattr(server, "browser_auth", None)
    return auth() if callable(auth) else {}


@pytest.fixture
def fleet(server: ServerProcess, spawn_agent: Callable[..., AgentProcess]) -> dict[str, AgentProcess]:
    agents = {rid: spawn_agent(rid, f"--start-pose={pose}") for rid, pose in FLEET.items()}
    with server.client() as c:
        for rid in FLEET:
            wait_robot(c, rid, driveable, timeout=30)
    return agents
